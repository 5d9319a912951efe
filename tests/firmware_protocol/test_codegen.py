"""Messages declared once (STYLE 21): the generated code and PROTOCOL.md follow the declaration.

``firmware_protocol/declaration.py`` is the one place a payload layout is written;
``python -m firmware_protocol.codegen`` derives the Python classes, ``MsgType`` and the C
header from it. These tests fail when a generated file is stale (someone edited it by hand,
or changed the declaration without regenerating) and when PROTOCOL.md's message tables say
something else than the declaration.
"""

from __future__ import annotations

import dataclasses
import re
import struct
from pathlib import Path

import pytest

import firmware_protocol as fp
from firmware_protocol import codegen
from firmware_protocol.declaration import MESSAGES, WIRE_TYPES

PROTOCOL_MD = Path(fp.__file__).resolve().parent / "PROTOCOL.md"

# PROTOCOL.md section 1: units are in the field names.
UNIT_SUFFIXES = (
    ("_dmm_s", "0.1 mm/s"),
    ("_um_s", "µm/s"),
    ("_um", "µm"),
    ("_ms", "ms"),
    ("_us", "µs"),
    ("_cv", "cV"),
    ("_da", "dA"),
    ("_hz", "Hz"),
)


def test_generated_files_are_current() -> None:
    """messages.py, the MsgType block of constants.py and c/dthc_messages.h are exactly what
    the generator makes from the declaration now."""
    stale = [
        str(path.relative_to(codegen.PACKAGE.parent))
        for path, text in codegen.generate().items()
        if path.read_text(encoding="utf-8") != text
    ]
    assert not stale, f"stale generated files {stale}: run `python -m firmware_protocol.codegen`"


def test_check_mode_fails_on_a_changed_declaration(monkeypatch: pytest.MonkeyPatch) -> None:
    """`codegen --check` exits 0 on the committed tree and 1, writing nothing, once the
    declaration says something the generated files do not (here: a field renamed)."""
    assert codegen.main(["--check"]) == 0
    before = {path: path.read_text(encoding="utf-8") for path in codegen.generate()}
    ack = next(m for m in MESSAGES if m.name == "ACK")
    renamed = dataclasses.replace(ack, fields=(dataclasses.replace(ack.fields[0], name="boot"),))
    changed = tuple(renamed if m is ack else m for m in MESSAGES)
    monkeypatch.setattr(codegen, "MESSAGES", changed)
    assert codegen.main(["--check"]) == 1
    assert {path: path.read_text(encoding="utf-8") for path in before} == before


def _protocol_table_rows() -> list[str]:
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    start = text.index("### 6.1 Host to board")
    end = text.index("## 7. Code tables")
    return [line.strip() for line in text[start:end].splitlines() if line.startswith("| 0x")]


def test_protocol_md_tables_match_the_declaration() -> None:
    """Every row of PROTOCOL.md's tables 6.1 and 6.2 (type, name, payload fields with their
    wire types, size, reply) reads as the declaration renders it, in the same order."""
    assert _protocol_table_rows() == codegen.protocol_rows()


def test_units_in_field_names_agree_with_the_declared_units() -> None:
    """A field's name suffix (PROTOCOL.md section 1) and its declared unit say the same."""
    for msg in MESSAGES:
        for field in msg.fields:
            expected = next((u for s, u in UNIT_SUFFIXES if field.name.endswith(s)), "")
            assert field.unit == expected, (msg.name, field.name, field.unit)


def test_python_messages_follow_the_declaration() -> None:
    """Each class has ``seq`` and then the declared fields in wire order; its struct layout
    covers exactly the declared fixed payload; MsgType carries the declared type codes."""
    assert [int(t) for t in fp.MsgType] == [m.type for m in MESSAGES]
    for msg in MESSAGES:
        cls = getattr(fp, msg.cls)
        assert cls._fields == ("seq", *(f.name for f in msg.fields)), msg.name
        msg_type, fmt = fp.LAYOUTS[cls]
        assert msg_type == fp.MsgType[msg.name] == msg.type
        fixed = sum(WIRE_TYPES[f.wire][0] for f in msg.fields if f.wire != "u16[N]")
        assert struct.calcsize("<" + fmt) == fixed, msg.name


def test_c_header_sizes_follow_the_declaration() -> None:
    """The generated C payload sizes are the declared ones (the C codec's tests check the
    C code against the golden vectors)."""
    header = codegen.MESSAGES_H.read_text(encoding="utf-8")
    sizes = dict(re.findall(r"#define DTHC_(\w+)_SIZE (\d+)", header))
    for msg in MESSAGES:
        assert int(sizes[msg.name]) == codegen.fixed_size(msg), msg.name
