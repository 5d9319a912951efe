# The two commands a newcomer needs: `make demo` and `make test`.
# Both do their own set-up on a fresh machine.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test demo lint typecheck unit bench broker browser systemd-tools clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# The integration tests run a real mosquitto, and the README's worked example its standard
# clients (mosquitto_pub, mosquitto_sub); install them where they are missing.
broker:
	@{ command -v mosquitto >/dev/null 2>&1 || test -x /usr/sbin/mosquitto; } && \
	  command -v mosquitto_pub >/dev/null 2>&1 || { \
	  echo "installing mosquitto and mosquitto-clients (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq mosquitto mosquitto-clients >/dev/null; }

# The operator panel is tested in a real browser: Debian's chromium, driven through its
# chromedriver; install them where they are missing.
browser:
	@{ command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; } || { \
	  echo "installing chromium and chromium-driver (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium chromium-driver >/dev/null; }

# Unit checks run systemd-analyze on the service file; install it where it is missing.
systemd-tools:
	@command -v systemd-analyze >/dev/null 2>&1 || { \
	  echo "installing systemd-analyze (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends systemd >/dev/null; } \
	  || echo "systemd-analyze unavailable: its tests will be skipped"

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

unit: $(STAMP)
	$(BIN)/pytest -q

test: $(STAMP) broker browser systemd-tools lint typecheck unit

bench: $(STAMP)
	for suite in codec control latency soak faults fuzz scale; do $(BIN)/dthc-bridge bench $$suite --json; done

demo: $(STAMP)
	$(BIN)/dthc-bridge demo

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache build *.egg-info
