"""Every task the daemon starts is kept (and so can be awaited): a ``create_task``,
``ensure_future`` or ``run_in_executor`` whose result is thrown away is a task the event
loop may garbage-collect mid-flight, and whose exception nobody sees (asyncio's docs: "Save
a reference to the result of this function"). A ``TaskGroup``'s ``create_task`` is kept and
awaited by the group itself, so ``group.create_task(...)`` as a statement is fine."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STARTERS = frozenset({"create_task", "ensure_future", "run_in_executor"})


def dropped_tasks(package: Path) -> list[str]:
    found: list[str] = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)):
                continue
            func = node.value.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            owner = func.value if isinstance(func, ast.Attribute) else None
            if isinstance(owner, ast.Name) and owner.id.endswith("group"):
                continue  # the TaskGroup keeps and awaits it
            if name in STARTERS:
                found.append(
                    f"{path.relative_to(package.parent)}:{node.lineno}: {name}(...) not kept"
                )
    return found


def test_no_task_of_the_daemon_is_started_and_dropped() -> None:
    """Each task started in dthc_bridge is assigned or added to a set its owner awaits."""
    problems = dropped_tasks(ROOT / "dthc_bridge")
    assert not problems, "\n".join(problems)


def test_a_dropped_task_is_found(tmp_path: Path) -> None:
    """The check itself: a bare create_task statement is named with its line."""
    package = tmp_path / "sample"
    package.mkdir()
    (package / "bad.py").write_text(
        "import asyncio\n\nasyncio.create_task(work())\ngroup.create_task(work())\n"
    )
    assert dropped_tasks(package) == ["sample/bad.py:3: create_task(...) not kept"]
