"""docs/INTERFACES.md states contracts that are true: every name it gives exists, every link
resolves, every module of the package sits in one layer of its table, and the formats, versions and
environment variables it quotes are the ones the code uses."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEXT = (ROOT / "docs" / "INTERFACES.md").read_text(encoding="utf-8")


def resolve(dotted: str):
    """The object a dotted name ``jerklab.x.y.Z.attr`` names (modules imported on the way)."""
    parts = dotted.split(".")
    obj = importlib.import_module(parts[0])
    for i, name in enumerate(parts[1:], 1):
        try:
            obj = getattr(obj, name)
        except AttributeError:
            obj = importlib.import_module(".".join(parts[: i + 1]))
    return obj


NAMES = sorted(set(re.findall(r"`(jerklab(?:\.[A-Za-z_][A-Za-z0-9_]*)+)`", TEXT)))


def test_the_page_names_many_things():
    assert len(NAMES) > 60


@pytest.mark.parametrize("dotted", NAMES)
def test_named_object_exists(dotted):
    resolve(dotted)


def test_links_resolve_in_the_repository():
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", TEXT)
    assert links
    bad = [
        link
        for link in links
        if "://" not in link and not (ROOT / "docs" / link).resolve().exists()
    ]
    assert bad == []


def _layer_table() -> dict[str, list[str]]:
    section = TEXT.split("## Layers", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| (core|models|rig|face) \| (.+) \|$", section, re.M)
    return {layer: re.findall(r"`([a-z_]+)`", mods) for layer, mods in rows}


def test_every_module_of_the_package_is_in_one_layer():
    """The table shown is jerklab._layers' table, and every top-level module is in it once."""
    from jerklab._layers import LAYER_NAMES, LAYERS

    layers = _layer_table()
    assert tuple(layers) == LAYER_NAMES
    listed = [m for mods in layers.values() for m in mods]
    assert len(listed) == len(set(listed)), "a module in two layers"
    assert {m: lay for lay, mods in layers.items() for m in mods if lay != "face"} == LAYERS
    top = {
        p.stem if p.suffix == ".py" else p.name
        for p in (ROOT / "jerklab").iterdir()
        if (p.suffix == ".py" or (p / "__init__.py").exists()) and not p.name.startswith("_")
    }
    assert top - {"resources"} <= set(listed), sorted(top - set(listed))


def test_the_quoted_formats_and_versions_are_the_codes():
    from jerklab import protocol
    from jerklab.ident import IdentData
    from jerklab.lab import handin
    from jerklab.rig import recording

    assert f"version {protocol.PROTOCOL_VERSION}" in TEXT
    assert f"`{','.join(recording.COLUMNS)}`" in TEXT
    assert f'"format": "{IdentData.FORMAT}"' in TEXT
    assert protocol.SYNC == bytes([0xA5, 0x5A]) and "`0xA5 0x5A`" in TEXT
    assert f"0..{protocol.MAX_PAYLOAD} bytes" in TEXT
    assert protocol.crc16_ccitt_false(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE, as stated
    assert f"`{handin.MANIFEST}`" in TEXT
    assert recording.REQUIRED_METADATA == ("Ts", "counts_per_rad", "volts_per_pwm")
    for key in recording.REQUIRED_METADATA:
        assert f"`{key}`" in TEXT


def test_the_environment_variables_are_read_where_the_table_says():
    section = TEXT.split("## Environment variables", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| (`JERKLAB_.+?) \| `(jerklab[a-z_.]*)` \|", section, re.M)
    assert len(rows) >= 7
    for variables, module in rows:
        path = ROOT / Path(*module.split("."))
        files = list(path.rglob("*.py")) if path.is_dir() else [path.with_suffix(".py")]
        source = "".join(f.read_text(encoding="utf-8") for f in files)
        for var in re.findall(r"`(JERKLAB_[A-Z_]+)`", variables):
            assert var in source, (var, module)
    read = set()
    for f in (ROOT / "jerklab").rglob("*.py"):
        read |= set(re.findall(r"\b(JERKLAB_[A-Z_]+)\b", f.read_text(encoding="utf-8")))
    assert read <= set(re.findall(r"`(JERKLAB_[A-Z_]+)`", section)), "a variable not in the table"


def test_the_pin_map_is_the_drawn_one():
    from jerklab.wiring import CONNECTIONS

    section = TEXT.split("## The rig's wiring", 1)[1].split("\n## ", 1)[0]
    rows = {
        frozenset((f"Uno.{pin}", part.replace(" ", ".")))
        for pin, part in re.findall(r"^\| (D\d+) \| (\S+ \S+) \|", section, re.M)
    }
    drawn = {
        frozenset((w.a, w.b))
        for w in CONNECTIONS
        if w.a.startswith("Uno.D") or w.b.startswith("Uno.D")
    }
    assert len(rows) == 5 and rows == drawn
