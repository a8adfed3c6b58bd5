"""Shared test set-up: headless plotting, hypothesis profiles, system-tool checks, and the tiers.

The tiers: every test file's markers are in ``FILE_MARKS`` below (pyproject registers them,
``--strict-markers`` refuses any other). ``make check`` deselects all of them but ``verilog`` (the
fast tier, ``CHECK_MARKS`` in the Makefile); ``make test`` runs everything in parallel
(pytest-xdist, ``--dist loadgroup``): the files in ``ONE_WORKER`` keep their tests on one worker,
because their module-scoped fixtures start something costly or write to one fixed folder (a
simulated Uno, a hub, a browser, the book).
"""

from __future__ import annotations

import os
import shutil

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

from hypothesis import HealthCheck, settings  # noqa: E402

# "dev" keeps a local run quick and draws new cases every run; "ci" (set by .ci/run) runs the full
# case counts, derandomized so that a CI verdict is reproducible (a failure found by "dev" is kept
# as an @example in the test).
settings.register_profile("dev", max_examples=300, deadline=None)
settings.register_profile(
    "ci",
    max_examples=2000,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))

REQUIRE_TOOLS = os.environ.get("JERKLAB_REQUIRE_TOOLS", "") not in ("", "0")


def require_tool(*names: str) -> None:
    """Skip the calling test, with a message, when a system tool is missing.

    In CI (``JERKLAB_REQUIRE_TOOLS=1``, set by ``.ci/run``) a missing tool fails the
    test instead, so a green CI can never hide a skipped firmware or browser test.
    """
    missing = [n for n in names if shutil.which(n) is None and not os.path.exists(n)]
    if missing:
        msg = (
            f"needs {', '.join(missing)} (Debian packages; `.ci/run` installs them: "
            "sudo apt-get install make g++ gcc-avr avr-libc arduino-core-avr simavr "
            "libsimavr-dev iverilog chromium)"
        )
        if REQUIRE_TOOLS:
            pytest.fail(msg)
        pytest.skip(msg)


@pytest.fixture
def artifacts_dir(tmp_path_factory):
    """A folder whose files are kept after the run (``artifacts/`` at the repo root)."""
    root = os.path.join(os.path.dirname(os.path.dirname(__file__)), "artifacts")
    os.makedirs(root, exist_ok=True)
    return root


#: markers of whole test files (path under tests/): what a file needs beyond Python
FILE_MARKS = {
    "test_notebooks.py": ("notebook",),
    "test_book.py": ("notebook", "book"),
    "test_labs.py": ("notebook", "simavr"),
    "test_lab4.py": ("notebook", "simavr"),
    "test_browser.py": ("browser",),
    "test_hub.py": ("hub",),
    "test_packaging.py": ("packaging",),
    "test_arduino_ide.py": ("arduino",),
    "test_simavr.py": ("simavr",),
    "test_rig_simavr.py": ("simavr",),
    "test_rig_sequence_shaper_simavr.py": ("simavr",),
    "test_firmware.py": ("firmware", "simavr"),
    "test_firmware_fixed.py": ("firmware", "simavr"),
    "test_firmware_telemetry.py": ("firmware", "simavr"),
    "test_firmware_law.py": ("firmware", "simavr"),
    "test_rig_sequence_shaper.py": ("firmware",),
    "faults/test_safety.py": ("firmware",),
    "test_fpga.py": ("verilog",),
    "test_fpga_signals.py": ("verilog",),
    "test_figures_yang.py": ("verilog",),
}

#: files whose tests stay on one xdist worker (module-scoped servers, simulators or build folders)
ONE_WORKER = {
    "test_book.py",
    "test_browser.py",
    "test_hub.py",
    "test_packaging.py",
    "test_arduino_ide.py",
    "test_simavr.py",
    "test_rig_simavr.py",
    "test_rig_sequence_shaper_simavr.py",
    "test_firmware_telemetry.py",
}

_TESTS = os.path.dirname(os.path.abspath(__file__))


def _rel(item) -> str:
    return os.path.relpath(str(item.path), _TESTS).replace(os.sep, "/")


def pytest_collection_modifyitems(session, config, items):
    """Mark every test by its file (``FILE_MARKS``, ``ONE_WORKER``), and run tests/test_book.py last:
    it builds the book from the notebooks test_notebooks.py executed."""
    for item in items:
        rel = _rel(item)
        for name in FILE_MARKS.get(rel, ()):
            item.add_marker(getattr(pytest.mark, name))
        if rel in ONE_WORKER:
            item.add_marker(pytest.mark.xdist_group(rel))
    items.sort(key=lambda it: _rel(it) == "test_book.py")
