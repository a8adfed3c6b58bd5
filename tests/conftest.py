"""Shared test set-up: headless plotting, hypothesis profiles, system-tool checks."""

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


def pytest_collection_modifyitems(session, config, items):
    """Run tests/test_book.py last: it builds the book from the notebooks test_notebooks.py executed."""
    items.sort(
        key=lambda it: (
            it.nodeid.startswith("tests/test_book.py") or it.nodeid.startswith("test_book.py")
        )
    )
