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
# the rig's live plots (jerklab.rig.live) are off by default in the kernels the suite starts:
# the notebooks and worksheets run headless, where nobody watches them redraw, and each costs a
# figure per run; tests/test_rig_live.py and test_browser.py's live-plot tests turn them on
os.environ.setdefault("JERKLAB_LIVE_PLOT", "0")

from hypothesis import HealthCheck, settings  # noqa: E402

# "dev" keeps a local run quick and draws new cases every run; "ci" (set by .ci/run) runs the full
# case counts, derandomized so that a CI verdict is reproducible (a failure found by "dev" is kept
# as an @example in the test). Case counts come from these profiles only, no test sets
# ``max_examples`` (tests/test_suite_layout.py): a test whose one case costs more than about a
# tenth of a second in CI (a fit, a firmware run, a dense integration) takes the profile's
# "costly" share, a test whose case is itself a batch of 4000 moves the "batch" share (``cases``
# below). The ci counts (700, 70, 28) give 30842 cases in all where the tests' own counts gave
# 28650 (tests/test_suite_layout.py keeps the sum), in about the same time: a case costs 25-110 ms
# in most tests.
PROFILES = {
    "dev": dict(max_examples=100, deadline=None),
    "ci": dict(
        max_examples=700,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow],
    ),
}
#: a cost class -> the divisor of the profile's ``max_examples`` it runs
COST_SHARE = {"cheap": 1, "costly": 10, "batch": 25}
for _name, _kw in PROFILES.items():
    settings.register_profile(_name, **_kw)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))


def cases(cost: str, **kwargs) -> settings:
    """Hypothesis settings of the cost class ``cost``: its share (``COST_SHARE``) of the loaded
    profile's ``max_examples``.

    ``@cases("costly")`` on a test whose case takes a tenth of a second or more; other settings
    (``deadline``, ``suppress_health_check``) may be given as keywords, case counts may not.
    """
    if cost not in COST_SHARE:
        raise ValueError(f"cost must be one of {sorted(COST_SHARE)}, not {cost!r}")
    if "max_examples" in kwargs:
        raise TypeError("max_examples comes from the hypothesis profile (tests/conftest.py)")
    return settings(
        max_examples=max(1, settings.default.max_examples // COST_SHARE[cost]), **kwargs
    )


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


#: what ``connect("simavr")`` builds and runs: the sketch (avr-g++ and binutils on the Arduino
#: core) and the simulator harness (cc on simavr's headers)
SIMAVR_TOOLS = (
    "make",
    "cc",
    "avr-g++",
    "avr-size",
    "avr-nm",
    "/usr/share/arduino/hardware/arduino/avr/cores/arduino",
    "/usr/include/simavr/sim_avr.h",
)


def require_simavr() -> None:
    """``require_tool`` of everything a test on the simulated Uno needs (``SIMAVR_TOOLS``)."""
    require_tool(*SIMAVR_TOOLS)


@pytest.fixture(scope="session")
def host_driver():
    """The firmware core built for the host (``make -C firmware host``): the driver's path.

    Built once per test process; the build is serialised by a file lock, so parallel workers
    share firmware/build."""
    require_tool("g++", "make")
    from jerklab.rig.simavr import build_firmware

    return build_firmware("host")["host"]


@pytest.fixture(scope="module")
def forget_simavr_module():
    """Leave ``jerklab.rig.simavr`` un-imported after the module, as other modules' tests expect
    (tests/test_rig.py checks ``connect("simavr")`` with the module absent); a module that
    imports it uses this fixture (``pytestmark = pytest.mark.usefixtures(...)``)."""
    import sys

    yield
    sys.modules.pop("jerklab.rig.simavr", None)
    import jerklab.rig

    if hasattr(jerklab.rig, "simavr"):
        delattr(jerklab.rig, "simavr")


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
    "test_lab5.py": ("notebook",),
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
    "faults/test_firmware_mutants.py": ("firmware",),
    "test_fpga.py": ("verilog",),
    "test_fpga_signals.py": ("verilog",),
    "test_figures_yang.py": ("verilog",),
    "security/test_hub.py": ("hub",),
    "security/test_grading.py": ("notebook", "slow"),
    "security/test_hidden_motor.py": ("notebook", "slow"),
    "security/test_signing.py": ("slow",),
    "security/test_queue.py": ("browser",),
}

#: files whose tests stay on one xdist worker (module-scoped servers, simulators or build folders);
#: a file whose tests use a module-scoped fixture is kept together without being listed here
#: (``_group``), or each worker would start that fixture's server or grade its class again
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
    "security/test_hub.py",
    "security/test_grading.py",
    "security/test_hidden_motor.py",
    "test_notebooks.py",
}
#: files of ONE_WORKER that share one worker with another (two hubs must not start at once: both
#: make and remove the same Unix users, and removing one kills its processes)
SHARED_WORKER = {
    "security/test_hub.py": "test_hub.py",
    # the book is built from the notebooks test_notebooks.py executes: after them, on their worker
    "test_book.py": "test_notebooks.py",
    # the measured DC generator's four PEM fits (tests/_ident.py, cached per worker) once
    "test_figures_ident.py": "test_ident_generator.py",
}
#: the longest groups (minutes of one worker each) are handed out first, so that no worker starts
#: one of them near the end of the run while the other waits idle
LONG_GROUPS = (
    "test_notebooks.py",
    "test_browser.py",
    "security/test_grading.py",
    "test_hub.py",
    "test_packaging.py",
    "security/test_hidden_motor.py",
)

_TESTS = os.path.dirname(os.path.abspath(__file__))


def _rel(item) -> str:
    return os.path.relpath(str(item.path), _TESTS).replace(os.sep, "/")


def _group(item) -> str | None:
    """The xdist group of ``item``: its file's (ONE_WORKER, SHARED_WORKER), or its file when one
    of its fixtures is module-scoped; None: the test may run on any worker."""
    rel = _rel(item)
    if rel in ONE_WORKER:
        return SHARED_WORKER.get(rel, rel)
    info = getattr(item, "_fixtureinfo", None)
    defs = info.name2fixturedefs.values() if info is not None else ()
    if any(d.scope == "module" for ds in defs for d in ds):
        return SHARED_WORKER.get(rel, rel)
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(session, config, items):
    """Mark every test by its file (``FILE_MARKS``) and its group (``_group``); hand out the long
    groups first (``LONG_GROUPS``), tests/test_book.py after the notebooks it builds from.

    ``tryfirst``: pytest-xdist reads the ``xdist_group`` markers in its own hook of this name
    (it appends ``@group`` to each test id); after it, a marker added here has no effect and
    every test of a group may land on either worker.
    """
    for item in items:
        for name in FILE_MARKS.get(_rel(item), ()):
            item.add_marker(getattr(pytest.mark, name))
        group = _group(item)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))

    def order(item):
        group = _group(item)
        first = LONG_GROUPS.index(group) if group in LONG_GROUPS else len(LONG_GROUPS)
        return first, _rel(item) == "test_book.py"

    items.sort(key=order)  # stable: the collection order within each key


@pytest.fixture(autouse=True)
def _jerklab_environment_stays_put():
    """Put every ``JERKLAB_*`` variable back after each test.

    A command's ``main()`` run in-process sets them for its page or kernels (``jerklab app
    --profile`` sets the profile), and one left behind changes what a later test on the same
    worker connects to: a virtual rig with another motor, a Voilà page started with it.
    """
    before = {k: v for k, v in os.environ.items() if k.startswith("JERKLAB_")}
    yield
    for k in [k for k in os.environ if k.startswith("JERKLAB_") and k not in before]:
        del os.environ[k]
    os.environ.update(before)


#: ``JERKLAB_TEST_TIMELINE=FILE``: every worker appends one line per test phase to FILE (worker,
#: start and duration in seconds, phase, test id), to see how the workers share a run's time
_TIMELINE = os.environ.get("JERKLAB_TEST_TIMELINE")


if _TIMELINE:

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(item):
        yield from _timed(item, "setup")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(item):
        yield from _timed(item, "call")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(item):
        yield from _timed(item, "teardown")

    def _timed(item, phase):
        import time

        t0 = time.time()
        yield
        with open(_TIMELINE, "a") as f:
            worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
            f.write(f"{worker}\t{t0:.2f}\t{time.time() - t0:.2f}\t{phase}\t{item.nodeid}\n")
