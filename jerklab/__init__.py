"""jerklab: jerk-controlled positioning for the lab.

Planners (and the multi-axis ``plan_multi_axis``) are re-exported here; the other modules are imported by name
(``jerklab.plant``, ``jerklab.controller``, ``jerklab.sim``, ``jerklab.ident``,
``jerklab.rig``, ``jerklab.fpga``, ``jerklab.piezo``, ``jerklab.hysteresis``,
``jerklab.shaping``).
"""

from __future__ import annotations

from .multiaxis import plan_multi_axis
from .planner import (
    AnyStateProfile,
    Profile,
    ProfileSample,
    plan_batch,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)

__version__ = "0.1.0"

__all__ = [
    "AnyStateProfile",
    "Profile",
    "ProfileSample",
    "plan_batch",
    "plan_multi_axis",
    "plan_scurve",
    "plan_sine_jerk",
    "plan_sine_jerk_optimal",
    "plan_trapezoid",
    "__version__",
]
