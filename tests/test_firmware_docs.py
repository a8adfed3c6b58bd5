"""Firmware docs that cannot drift: the size numbers in firmware/README.md, docs/RIG.md and
docs/INSTRUCTOR.md are today's ``make -C firmware size``, and every firmware function or source
file a doc names exists in the firmware source."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import require_tool

from jerklab.rig.simavr import build_firmware

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
# the docs that state the sketch's size, in the one form the test reads
SIZE_DOCS = ("firmware/README.md", "docs/RIG.md", "docs/INSTRUCTOR.md")
SIZE_RE = re.compile(
    r"flash ([\d,]+) of 32,256 B \(([\d.]+) %\), RAM ([\d,]+) of 2,048 B \(([\d.]+) %\)"
)
# the docs that name firmware functions
NAME_DOCS = (
    "firmware/README.md",
    "firmware/PROTOCOL.md",
    "docs/THEORY.md",
    "docs/RIG.md",
    "docs/INSTRUCTOR.md",
    "docs/INTERFACES.md",
    "README.md",
)


def _source():
    files = [
        *sorted((FIRMWARE / "jerklab_rig").rglob("*.h")),
        *sorted((FIRMWARE / "jerklab_rig").rglob("*.cpp")),
        FIRMWARE / "jerklab_rig" / "jerklab_rig.ino",
        FIRMWARE / "host" / "jl_host.cpp",
        FIRMWARE / "simavr" / "jl_simavr.c",
    ]
    return {f.name: f.read_text() for f in files}


def _names(text):
    """Backquoted firmware names: ``Class::member`` (optionally ``jl::`` first and ``()`` after),
    ``jl::Name`` and ``jl_name`` (a function, or a source file's stem)."""
    out = set()
    for m in re.finditer(r"`((?:jl::)?[A-Za-z_]\w*(?:::\w+)*|jl_\w+)(?:\(\))?`", text):
        name = m.group(1)
        if "::" in name or name.startswith("jl_"):
            out.add(name)
    return out


def _found(name, src):
    """Whether the firmware source has ``name``: a class's member function (or constructor), a
    type or (written ``jl::name``) a function declared in namespace jl, or a jl_ function,
    assembly routine or source file."""
    text = "\n".join(src.values())
    qualified = name.startswith("jl::")
    if qualified:
        name = name[4:]
    if "::" in name:
        *scope, member = name.split("::")
        cls = scope[-1]
        if not re.search(rf"\b(?:class|struct)\s+{cls}\b", text):
            return False
        return member == cls or bool(re.search(rf"\b{member}\s*\(", text))
    if not name.startswith("jl_"):  # a type (or, written jl::name, a function of namespace jl)
        if re.search(rf"\b(?:class|struct)\s+{name}\b", text):
            return True
        return qualified and bool(re.search(rf"^\w[\w\s\*&:]*\b{name}\s*\(", text, re.M))
    stems = {f.rsplit(".", 1)[0] for f in src}
    return name in stems or bool(re.search(rf"\b{name}\s*[:(]", text))


def test_every_firmware_name_a_doc_gives_is_in_the_source():
    src = _source()
    missing = {}
    for doc in NAME_DOCS:
        for name in sorted(_names((ROOT / doc).read_text())):
            if not _found(name, src):
                missing.setdefault(doc, []).append(name)
    assert not missing, f"firmware names in the docs that the source does not have: {missing}"


def test_the_name_check_finds_a_missing_name():
    src = _source()
    assert _names("the float `Pid::step_fast` and `jl_pidq_step`, `jl::PidQ::step()`") == {
        "Pid::step_fast",
        "jl_pidq_step",
        "jl::PidQ::step",
    }
    assert not _found("Pid::step_fast", src) and not _found("Device::no_such_thing", src)
    assert not _found("jl_no_such_routine", src)
    assert _found("Pid::step", src) and _found("jl_pidq_step", src) and _found("jl_law", src)


@pytest.fixture(scope="module")
def size():
    require_tool(
        "avr-g++", "avr-size", "make", "/usr/share/arduino/hardware/arduino/avr/cores/arduino"
    )
    out = build_firmware("avr", "size")["output"]
    m = re.search(
        r"flash (\d+) / 32256 bytes \(([\d.]+) %\), RAM (\d+) / 2048 bytes \(([\d.]+) %\)", out
    )
    assert m, out
    return int(m.group(1)), m.group(2), int(m.group(3)), m.group(4)


@pytest.mark.parametrize("doc", SIZE_DOCS)
def test_size_numbers_in_the_docs_are_todays(size, doc):
    text = (ROOT / doc).read_text()
    found = SIZE_RE.findall(text)
    assert found, f"{doc} states no size as 'flash N of 32,256 B (P %), RAM N of 2,048 B (P %)'"
    flash, fpct, ram, rpct = size
    want = (f"{flash:,}", fpct, f"{ram:,}", rpct)
    for f in found:
        assert f == want, f"{doc} says {f}, make -C firmware size says {want}"
