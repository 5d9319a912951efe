"""The README's worked example for sender authors, run as written with the standard
mosquitto_pub / mosquitto_sub clients against the daemon (mosquitto, daemon and mock board
as their own processes). Only the broker port and the base topic are substituted."""

from __future__ import annotations

import asyncio
import json
import re
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.procs import die_with_parent

pytestmark = [
    pytest.mark.slow,
    pytest.mark.timeout(120),
    pytest.mark.skipif(shutil.which("mosquitto_pub") is None, reason="mosquitto-clients"),
]

README = (Path(__file__).parents[2] / "README.md").read_text()


def example_commands() -> list[str]:
    section = README[README.index("## Writing a sender") :]
    block = re.search(r"```sh\n(.*?)```", section, re.DOTALL)
    assert block is not None
    return [line for line in block.group(1).splitlines() if line.startswith("mosquitto_")]


def localised(command: str, stack: Stack) -> list[str]:
    argv = shlex.split(command.replace("dthc/table1", stack.root).rstrip(" &"))
    return [*argv[:1], "-p", str(stack.broker.port), "-V", "mqttv311", *argv[1:]]


async def test_the_worked_example_answers_as_the_readme_says(tmp_path: Path) -> None:
    commands = example_commands()
    assert commands[0].startswith("mosquitto_sub")
    async with Stack(StackOptions(tmp_path, broker="mosquitto")) as stack:
        sub = await asyncio.create_subprocess_exec(
            *localised(commands[0], stack), stdout=subprocess.PIPE, preexec_fn=die_with_parent()
        )
        try:
            await asyncio.sleep(0.5)  # subscribed before the first request
            for command in commands[1:]:
                pub = await asyncio.create_subprocess_exec(*localised(command, stack))
                assert await asyncio.wait_for(pub.wait(), 10) == 0, command
                await asyncio.sleep(0.3)  # answers in the order of the requests
            await asyncio.sleep(0.5)
        finally:
            sub.terminate()
        raw, _ = await asyncio.wait_for(sub.communicate(), 5)
        out = raw.decode()
        await stack.finish()
    answers = [
        json.loads(line.split(" ", 1)[1])
        for line in out.splitlines()
        if "/response/" in line.split(" ", 1)[0]
    ]
    by = [(a.get("transaction"), a["status"], a.get("error", "")) for a in answers]
    assert by[0][:2] == ("ex-1", "ok")
    assert by[1][:2] == ("ex-2", "ok")
    assert answers[2] == answers[1]  # the repeat: the cached answer, not run twice
    assert by[3][:2] == ("ex-2", "error")
    assert "already used for a different gcode request" in by[3][2]
    assert by[4][:2] == ("ex-2", "error")  # the same transaction under another request name
    assert "already used for a 'gcode' request; this is a 'status' request" in by[4][2]
    assert by[5][:2] == ("ex-3", "error")
    assert "G200 A" in by[5][2]
    assert by[6][:2] == (None, "ok")  # the motion report
    assert answers[6]["data"] == {"used": False}  # the mock board measures XY speed itself
    assert len(answers) == 7
    assert any('"online"' in line for line in out.splitlines() if "availability" in line)
