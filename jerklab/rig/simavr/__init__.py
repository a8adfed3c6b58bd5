"""The real rig firmware on a simulated Uno: build helpers and the simavr harness launcher.

Two rooms, one public face (the names below, as before the split):

- :mod:`jerklab.rig.simavr.build`: ``make -C firmware`` from Python (:func:`build_firmware`,
  :func:`firmware_dir`, :class:`FirmwareBuildError`).
- :mod:`jerklab.rig.simavr.harness`: the harness launcher (:func:`launch`,
  :class:`SimulatedUno`, :class:`HarnessError`, :func:`tools_missing`).

``jerklab.rig.connect("simavr")`` looks this package up through ``sys.modules`` at call time,
so a test can put a stand-in launcher in its place.
"""

from __future__ import annotations

from jerklab.rig.simavr.build import FirmwareBuildError, build_firmware, firmware_dir
from jerklab.rig.simavr.harness import HarnessError, SimulatedUno, launch, tools_missing

__all__ = [
    "firmware_dir",
    "build_firmware",
    "FirmwareBuildError",
    "launch",
    "SimulatedUno",
    "HarnessError",
    "tools_missing",
]
