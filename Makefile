# The two commands a newcomer needs: `make demo` and `make test`.
# Both do their own set-up on a fresh machine.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test demo lint typecheck unit bench broker browser systemd-tools avr-tools flash-tools firmware board-lib cc-tools codegen cncjs clean

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

# The grbl port is tested with a real grbl sender: CNCjs from the npm registry (its serial
# module ships prebuilt; nothing compiles), at the versions of tests/e2e/cncjs's lock file,
# in a cache folder outside the checkout (about 230 MB, 40 s once). Node.js and npm from
# Debian where missing. Reinstalled when the lock file changes.
CNCJS_DIR ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/dthc-bridge/cncjs
export CNCJS_DIR
cncjs:
	@{ command -v node >/dev/null 2>&1 && command -v npm >/dev/null 2>&1; } || { \
	  echo "installing nodejs and npm (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq nodejs npm >/dev/null; }
	@cmp -s tests/e2e/cncjs/package-lock.json "$(CNCJS_DIR)/package-lock.json" && \
	  test -x "$(CNCJS_DIR)/node_modules/cncjs/bin/cncjs" || { \
	  echo "installing CNCjs from the npm registry into $(CNCJS_DIR)"; \
	  mkdir -p "$(CNCJS_DIR)" && cp tests/e2e/cncjs/package.json tests/e2e/cncjs/package-lock.json "$(CNCJS_DIR)/" && \
	  npm ci --prefix "$(CNCJS_DIR)" --no-audit --no-fund --loglevel=error; }

# Unit checks run systemd-analyze on the service file; install it where it is missing.
systemd-tools:
	@command -v systemd-analyze >/dev/null 2>&1 || { \
	  echo "installing systemd-analyze (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends systemd >/dev/null; } \
	  || echo "systemd-analyze unavailable: its tests will be skipped"

# The reference firmware is built with Debian's avr-gcc and tested as the very ELF users
# flash, on simavr (an emulated ATmega): install the toolchain and simavr where missing.
AVR_PACKAGES := gcc-avr avr-libc binutils-avr simavr libsimavr-dev libsimavrparts1 libelf-dev pkg-config
avr-tools:
	@{ command -v avr-gcc >/dev/null 2>&1 && command -v avr-size >/dev/null 2>&1 && \
	  test -f /usr/include/simavr/sim_avr.h && test -f /usr/lib/avr/include/avr/io.h && \
	  ls /usr/lib/*/libsimavr.so* >/dev/null 2>&1 && command -v pkg-config >/dev/null 2>&1 && \
	  test -f /usr/include/libelf.h; } || { \
	  echo "installing the AVR toolchain and simavr (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $(AVR_PACKAGES) >/dev/null; }

# Flashing as a table owner does: Debian's avrdude through Arduino's own bootloaders
# (arduino-core-avr ships them as HEX, loaded by the emulated board from /usr/share).
FLASH_PACKAGES := avrdude arduino-core-avr
flash-tools:
	@{ command -v avrdude >/dev/null 2>&1 && \
	  test -f /usr/share/arduino/hardware/arduino/avr/bootloaders/stk500v2/stk500boot_v2_mega2560.hex && \
	  test -f /usr/share/arduino/hardware/arduino/avr/bootloaders/atmega/ATmegaBOOT_168_atmega328.hex; } || { \
	  echo "installing avrdude and Arduino's bootloaders (apt-get)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $(FLASH_PACKAGES) >/dev/null; }

# The mock device runs the firmware's board logic (firmware/board/) as a shared library
# (firmware/build/host/libdthc_board.so, STYLE 23): it needs a C compiler and make; install
# Debian's where they are missing.
cc-tools:
	@{ command -v make >/dev/null 2>&1 && { command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1; }; } || { \
	  echo "installing a C compiler (apt-get gcc libc6-dev make)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends gcc libc6-dev make >/dev/null; }

board-lib: cc-tools
	$(MAKE) --no-print-directory -C firmware host

# The HEX and ELF a table owner flashes (Mega 2560 and Nano), their flash and RAM use, and
# the emulated-board harness that runs them.
firmware: avr-tools flash-tools
	$(MAKE) --no-print-directory -C firmware
	$(MAKE) --no-print-directory -C firmware/emulator

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m firmware_protocol.codegen --check

# After changing a message in firmware_protocol/declaration.py: regenerate messages.py,
# MsgType and firmware_protocol/c/dthc_messages.h (STYLE 21: messages declared once).
codegen: $(STAMP)
	$(BIN)/python -m firmware_protocol.codegen

typecheck: $(STAMP)
	$(BIN)/mypy

# Two workers, a test file each at a time (module fixtures, such as one emulated board,
# stay shared): the end-to-end tests spend most of their time waiting on real time.
unit: $(STAMP) board-lib
	$(BIN)/pytest -q -n 2 --dist loadfile

test: $(STAMP) broker browser systemd-tools cncjs firmware lint typecheck unit

bench: $(STAMP) board-lib
	for suite in codec control latency soak faults fuzz scale; do $(BIN)/dthc-bridge bench $$suite --json; done

demo: $(STAMP) board-lib
	$(BIN)/dthc-bridge demo

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache build *.egg-info
