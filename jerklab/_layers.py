"""The layers of jerklab: who may import whom (the one table; docs/INTERFACES.md shows it).

A module imports only from its own layer (without a cycle) and the layers before it; the base
utilities (:data:`BASE`) serve every layer. The one way up is a result's ``.plot()`` handing
itself to ``jerklab.plots`` by one late import. ``tests/test_import_graph.py`` builds the graph
from every import statement and checks it against this table; ``tests/test_interfaces.py``
checks that docs/INTERFACES.md shows the same table.
"""

from __future__ import annotations

__all__ = ["LAYER_NAMES", "LAYERS", "BASE", "layer_of"]

#: lowest first
LAYER_NAMES = ("core", "models", "rig", "face")

#: first name under ``jerklab.`` -> its layer; a module not listed belongs to the face
LAYERS = {
    **dict.fromkeys(
        ("law", "paper", "protocol", "planner", "_onedof", "plant", "controller"), "core"
    ),
    **dict.fromkeys(
        ("sim", "metrics", "ident", "shaping", "piezo", "hysteresis", "fpga", "multiaxis")
        + ("tuning", "peers"),
        "models",
    ),
    "rig": "rig",
}

#: usable by every layer
BASE = ("jerklab", "jerklab._validate", "jerklab._lazy", "jerklab._vocab", "jerklab._layers")
BASE += ("jerklab.resources",)


def layer_of(module: str) -> str:
    """The layer of a dotted module name (``"base"`` for the base utilities)."""
    if module in BASE:
        return "base"
    first = module.split(".")[1] if "." in module else ""
    return LAYERS.get(first, "face")
