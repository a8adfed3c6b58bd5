"""A module imported on first use, so that importing jerklab stays light.

python-control imports matplotlib when it is imported; the computing modules (plant,
controller, ident, piezo) only need it when a transfer function is asked for, so they hold
``ct = lazy_module("control")`` and the import happens on the first ``ct.tf(...)``.
"""

from __future__ import annotations

import importlib


class lazy_module:  # noqa: N801 - used like a module
    """Stand-in for the module ``name``: any attribute access imports it and forwards."""

    __slots__ = ("_name",)

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr):
        return getattr(importlib.import_module(self._name), attr)

    def __repr__(self):
        return f"<lazy module {self._name!r}>"
