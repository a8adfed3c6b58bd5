"""jerklab: jerk-controlled positioning for the lab.

Planners are re-exported here; the other modules are imported by name
(``jerklab.plant``, ``jerklab.controller``, ``jerklab.sim``, ``jerklab.ident``,
``jerklab.rig``, ``jerklab.fpga``, ``jerklab.piezo``, ``jerklab.hysteresis``).
"""
from __future__ import annotations

__version__ = "0.1.0"
