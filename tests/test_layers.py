"""The layers docs/ARCHITECTURE.md draws are the layers the imports follow.

Every ``import`` and ``from ... import`` in the four packages is read with :mod:`ast`
(function-level and ``TYPE_CHECKING`` imports included: a dependency is a dependency), and
each is checked against :data:`LAYERS`, the one declaration of who may import whom inside
``dthc_bridge``, and against the rules between the packages. A failure names the module,
the line and the import that goes against the direction.

Cycles are checked at two levels: between the components of :data:`LAYERS` (a package such
as ``dthc_bridge.mqtt`` or a top-level module such as ``dthc_bridge.service``), where the
declared table must itself be acyclic and every import must be one it allows, so no
component cycle can exist; and between single modules, over the whole import graph, which
also catches a cycle inside one component.

ARCHITECTURE.md carries the same table (the block after "Who may import whom"), checked here
against :data:`LAYERS` so the page cannot drift from what is enforced.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("firmware_protocol", "dthc_bridge", "mock_device", "dthc_tools")
ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"

# Who may import whom inside dthc_bridge, lowest layer first: each component (a package,
# or a top-level module) and what of the project it may import besides itself. A target is
# a module prefix: "controller.dialect" allows that module only, "controller" the package.
# "fp" is firmware_protocol, "fp.constants" its constants module alone.
LAYERS: dict[str, tuple[str, ...]] = {
    "__init__": (),  # dthc_bridge itself: its version, nothing else
    "backoff": (),
    "events": (),
    "config_paths": (),
    "cut_params": (),
    "units": (),
    "transport": (),
    "link": ("transport", "backoff", "fp"),
    "board": ("link", "fp"),
    "materials": ("cut_params", "units"),
    "controller": ("cut_params", "units", "materials", "fp.constants"),
    "code_map": ("controller.words",),
    "consumables": ("materials.store",),
    "port": ("events", "controller.dialect"),
    "requests": ("port", "controller"),
    "service": (
        "port", "requests", "board", "link", "controller", "materials", "consumables",
        "events", "fp",
    ),
    "mqtt": ("port", "requests", "backoff"),
    "config": ("controller", "link", "board", "mqtt.settings", "code_map", "fp"),
    "program": ("controller", "units", "materials", "code_map", "config"),
    "logs": ("link.frametrace",),
    "conformance": ("link", "transport", "logs", "fp"),
    "deploy": ("__init__", "mqtt.roles", "mqtt.settings", "mqtt.topics"),
    "daemon": (
        "board", "config", "consumables", "controller", "deploy.sdnotify", "link",
        "materials", "mqtt", "service", "transport", "fp",
    ),
    "cli": (
        "config", "config_paths", "daemon", "deploy.install", "logs", "program",
        "conformance",
    ),
    "__main__": ("cli",),
}  # fmt: skip

# Third-party libraries only one component of the daemon may import.
ONLY_IN = {
    "serial": "transport",
    "serial_asyncio_fast": "transport",
    "usb": "transport",
    "aiomqtt": "mqtt",
    "paho": "mqtt",
}
# The wire format is sans-io: none of these, anywhere in firmware_protocol.
NOT_IN_WIRE_FORMAT = ("asyncio", "serial", "serial_asyncio_fast", "usb", "socket", "selectors")
# The mock board reads G-code by the daemon's own tokeniser and keeps a program's modal
# state in the same type as every other reader (program/modal.py), and nothing else of it.
MOCK_MAY_IMPORT = (
    "firmware_protocol", "mock_device", "dthc_bridge.controller.words",
    "dthc_bridge.program.modal", "dthc_bridge.units",
)  # fmt: skip


@dataclass(frozen=True)
class Import:
    module: str  # the importer, dotted
    path: Path
    line: int
    target: str  # what it imports, dotted: a module of ours, or a top-level third party
    type_only: bool = False  # under ``if TYPE_CHECKING:``: for the type checker alone

    def __str__(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line} imports {self.target}"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {
        _module_name(path): path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
    }


MODULES = _modules()


def _resolve(importer: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = importer.split(".")
    if not is_package:
        base.pop()
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def _is_type_checking(node: ast.AST) -> bool:
    test = node.test if isinstance(node, ast.If) else None
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports_of(module: str, path: Path) -> Iterator[Import]:
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    type_only = {
        id(inner)
        for block in ast.walk(tree) if _is_type_checking(block)
        for inner in ast.walk(block)
    }  # fmt: skip
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(module, path, node.lineno, alias.name, id(node) in type_only)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node)
            for alias in node.names:
                # ``from pkg import sub`` imports the submodule when there is one
                sub = f"{base}.{alias.name}"
                target = sub if sub in MODULES else base
                yield Import(module, path, node.lineno, target, id(node) in type_only)


ALL_IMPORTS = [imp for module, path in MODULES.items() for imp in _imports_of(module, path)]


def _ours(target: str) -> bool:
    return target.split(".", maxsplit=1)[0] in PACKAGES


def _short(module: str) -> str:
    """``dthc_bridge.mqtt.topics`` -> ``mqtt.topics``; ``dthc_bridge`` -> ``__init__``;
    ``firmware_protocol.x`` -> ``fp.x``."""
    if module == "dthc_bridge":
        return "__init__"
    if module.startswith("dthc_bridge."):
        return module.removeprefix("dthc_bridge.")
    if module == "firmware_protocol" or module.startswith("firmware_protocol."):
        return "fp" + module.removeprefix("firmware_protocol")
    return module


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def component_of(module: str) -> str | None:
    """The LAYERS component a dthc_bridge module belongs to (None: undeclared)."""
    short = _short(module)
    found = [c for c in LAYERS if _within(short, c)]
    return max(found, key=len) if found else None


def layer_violations() -> list[str]:
    out: list[str] = []
    for imp in ALL_IMPORTS:
        if not imp.module.startswith("dthc_bridge"):
            continue
        mine = component_of(imp.module)
        if mine is None:
            out.append(f"{imp.path.relative_to(ROOT)}: module in no declared layer")
            continue
        top = imp.target.split(".")[0]
        if top in ONLY_IN and ONLY_IN[top] != mine:
            out.append(f"{imp}: only {ONLY_IN[top]} may import {top}")
            continue
        if not _ours(imp.target):
            continue
        if top in ("dthc_tools", "mock_device"):
            out.append(f"{imp}: the runtime never imports {top}")
            continue
        target = _short(imp.target)
        if top == "dthc_bridge" and component_of(imp.target) == mine:
            continue
        if any(_within(target, allowed) for allowed in LAYERS[mine]):
            continue
        allowed = ", ".join(LAYERS[mine]) or "nothing of the project"
        out.append(f"{imp}: {mine} may import only {allowed}")
    return sorted(set(out))


def package_violations() -> list[str]:
    out: list[str] = []
    for imp in ALL_IMPORTS:
        top = imp.target.split(".")[0]
        if imp.module.startswith("firmware_protocol"):
            if _ours(imp.target) and top != "firmware_protocol":
                out.append(f"{imp}: the wire format imports nothing of the project")
            if top in NOT_IN_WIRE_FORMAT:
                out.append(f"{imp}: the wire format is sans-io")
        elif (
            imp.module.startswith("mock_device")
            and _ours(imp.target)
            and not any(_within(imp.target, m) for m in MOCK_MAY_IMPORT)
        ):
            out.append(f"{imp}: the mock may import only {', '.join(MOCK_MAY_IMPORT)}")
    return sorted(set(out))


def module_cycles() -> list[list[str]]:
    """Every import cycle between modules (Tarjan's strongly connected components). A
    type-only import does not close one: the state handlers (controller/states.py) name the
    CutSequence that dispatches to them and that they act on, for the type checker only;
    nothing is imported at run time, and the layer rules above still count it."""
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for imp in ALL_IMPORTS:
        if imp.target in MODULES and imp.target != imp.module and not imp.type_only:
            graph[imp.module].add(imp.target)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return cycles


def render_layers() -> str:
    """LAYERS as ARCHITECTURE.md shows it: one component a line, what it may import."""
    width = max(len(c) for c in LAYERS)
    return "\n".join(
        f"{component:<{width}}  -> {' '.join(allowed) or '(nothing of the project)'}"
        for component, allowed in LAYERS.items()
    )


def test_the_declared_layers_have_no_cycle_and_name_only_real_modules() -> None:
    """Each component may import only components declared before it, so none can import
    another that imports it back; and every name in the table is a real module."""
    seen: list[str] = []
    for component, allowed in LAYERS.items():
        for target in allowed:
            owner = component_of("firmware_protocol" if target == "fp" else f"dthc_bridge.{target}")
            assert target.startswith("fp") or owner in seen, (component, target)
        seen.append(component)
    short_modules = {_short(m) for m in MODULES}
    for name in {*LAYERS, *(t for ts in LAYERS.values() for t in ts)}:
        assert any(_within(m, name) for m in short_modules), f"no module {name}"


def test_every_daemon_import_goes_down_the_declared_layers() -> None:
    """A module of dthc_bridge imports only its own component and what LAYERS allows it;
    pyserial/pyusb only in transport, aiomqtt/paho only in mqtt; never a tool or the mock."""
    problems = layer_violations()
    assert not problems, "imports against the layers:\n" + "\n".join(problems)


def test_the_wire_format_and_the_mock_keep_to_their_side() -> None:
    """firmware_protocol imports nothing of the project and no I/O library; mock_device
    imports the wire format and the daemon's G-code tokeniser only."""
    problems = package_violations()
    assert not problems, "\n".join(problems)


def test_nothing_but_the_tools_imports_the_tools() -> None:
    """dthc_tools may import everything; nothing outside it imports it."""
    problems = [
        str(imp)
        for imp in ALL_IMPORTS
        if imp.target.split(".")[0] == "dthc_tools" and not imp.module.startswith("dthc_tools")
    ]
    assert not problems, "\n".join(problems)


def test_no_module_import_cycle() -> None:
    """No two modules of the four packages import each other, directly or through others."""
    cycles = module_cycles()
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_architecture_md_draws_the_enforced_layers() -> None:
    """The table under "Who may import whom" in docs/ARCHITECTURE.md is LAYERS."""
    text = ARCHITECTURE.read_text()
    match = re.search(r"Who may import whom.*?\n```text\n(.*?)\n```", text, re.S)
    assert match is not None, "ARCHITECTURE.md has no layer table after 'Who may import whom'"
    assert match.group(1).strip() == render_layers(), (
        "ARCHITECTURE.md's layer table differs from tests/test_layers.py LAYERS; it should be:\n"
        + render_layers()
    )


@pytest.mark.parametrize(
    ("module", "target", "expected"),
    [
        ("dthc_bridge.mqtt.gateway", "dthc_bridge.controller.plasma", "mqtt may import only"),
        ("dthc_bridge.service", "dthc_bridge.mqtt.gateway", "service may import only"),
        ("dthc_bridge.transport.serial", "aiomqtt", "only mqtt may import aiomqtt"),
        ("dthc_bridge.board", "dthc_tools.demo", "the runtime never imports dthc_tools"),
    ],
)
def test_an_import_against_the_direction_is_named(
    module: str, target: str, expected: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check itself: a planted upward import fails, naming the module and the import."""
    path = MODULES[module]
    monkeypatch.setattr(
        "tests.test_layers.ALL_IMPORTS", [*ALL_IMPORTS, Import(module, path, 1, target)]
    )
    problems = layer_violations()
    assert any(expected in p and target in p and str(path.relative_to(ROOT)) in p for p in problems)


def test_a_module_cycle_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """The check itself: the tokeniser importing the G-code parser (which imports it) is a
    cycle, named by its modules."""
    module = "dthc_bridge.controller.words"
    planted = Import(module, MODULES[module], 1, "dthc_bridge.controller.gcode")
    monkeypatch.setattr("tests.test_layers.ALL_IMPORTS", [*ALL_IMPORTS, planted])
    assert ["dthc_bridge.controller.gcode", module] in module_cycles()
