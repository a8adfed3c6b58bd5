"""The worksheets' check cells, without otter-grader on the student's machine.

A worksheet's checks are written in otter-grader's format (``otter assign`` puts them in the
notebook's metadata, ``otter run`` grades with them), but a student only needs them to *run*:
``grader.check("K")`` executes the doctest cases of check ``K`` in the notebook's namespace and
shows right or wrong with the check's hint. :class:`Notebook` does that with the standard
library's :mod:`doctest`, so ``pip install "jerklab[lab]"`` needs neither otter-grader nor what
it pulls in (nbconvert's PDF export and with it the Playwright package); the instructor's grading
(``python -m jerklab.lab grade``, extra ``jerklab[labs]``) still uses otter-grader itself.

>>> grader = Notebook("lab1_identify.ipynb")    # doctest: +SKIP
>>> grader.check("K")                            # doctest: +SKIP
✘ K: K is too high beyond the tolerance (4 %): did you take the slope of steady speed ...
"""

from __future__ import annotations

import doctest
import html
import inspect
import json
from pathlib import Path

from jerklab.resources import share_path

__all__ = ["Notebook", "CheckOutcome", "load_tests"]


def load_tests(notebook) -> dict:
    """The checks stored in a worksheet's metadata (otter's ``metadata.otter.tests``).

    Parameters
    ----------
    notebook : str or path
        The worksheet's file name. It is looked for as given (the working folder of a running
        worksheet), then among the worksheets shipped with jerklab (a renamed or moved copy
        still finds its checks).

    Raises
    ------
    FileNotFoundError
        If neither the file nor a shipped worksheet of that name exists.
    ValueError
        If the file holds no checks.
    """
    path = Path(notebook)
    candidates = [path]
    try:
        candidates.append(share_path("notebooks") / "labs" / path.name)
    except FileNotFoundError:
        pass
    for p in candidates:
        if p.is_file():
            meta = json.loads(p.read_text(encoding="utf-8")).get("metadata", {})
            tests = meta.get("otter", {}).get("tests")
            if not tests:
                raise ValueError(f"notebook: {p} holds no checks (no metadata.otter.tests)")
            return tests
    raise FileNotFoundError(
        f"notebook: no worksheet named {str(notebook)!r} here or among jerklab's "
        "worksheets; pass the worksheet's file name, e.g. 'lab1_identify.ipynb'"
    )


class CheckOutcome:
    """The result of one ``grader.check``: ``passed`` and the hint or confirmation shown."""

    def __init__(self, name: str, passed: bool, message: str):
        self.name, self.passed, self.message = name, passed, message

    def __bool__(self):
        return self.passed

    def __repr__(self):
        mark = "✔" if self.passed else "✘"
        return f"{mark} {self.name}: {self.message}" if self.message else f"{mark} {self.name}"

    def _repr_html_(self):
        color = "#1a7f37" if self.passed else "#b3261e"
        return (
            f'<p style="color:{color};font-family:monospace;white-space:pre-wrap">'
            f"{html.escape(repr(self))}</p>"
        )


class _Collect(doctest.DocTestRunner):
    """A doctest runner that keeps the first failure's message instead of printing a report."""

    def __init__(self):
        super().__init__(optionflags=doctest.ELLIPSIS, verbose=False)
        self.failure = None

    def report_failure(self, out, test, example, got):
        if self.failure is None:
            self.failure = f"expected {example.want.strip()!r}, got {got.strip()!r}"

    def report_unexpected_exception(self, out, test, example, exc_info):
        if self.failure is None:
            exc = exc_info[1]
            self.failure = (
                str(exc)
                if isinstance(exc, AssertionError) and str(exc)
                else f"{type(exc).__name__}: {exc}"
            )


class Notebook:
    """``otter.Notebook``'s ``check`` for a student: the worksheet's checks, run in place.

    Parameters
    ----------
    notebook : str or path
        The worksheet's file name (see :func:`load_tests`).
    """

    def __init__(self, notebook):
        self.notebook = str(notebook)
        self.tests = load_tests(notebook)

    def check(self, name: str, global_env: dict | None = None) -> CheckOutcome:
        """Run check ``name`` in the caller's namespace (the notebook's) and show the outcome.

        Parameters
        ----------
        name : str
            The check's name, as in the worksheet's ``grader.check("...")`` cells.
        global_env : dict, optional
            The namespace to run in; by default the caller's globals.
        """
        if name not in self.tests:
            raise KeyError(
                f"name: no check {name!r} in {self.notebook} (known: {sorted(self.tests)})"
            )
        env = dict(
            global_env if global_env is not None else inspect.currentframe().f_back.f_globals
        )
        parser, runner = doctest.DocTestParser(), _Collect()
        for suite in self.tests[name].get("suites", []):
            for case in suite.get("cases", []):
                if suite.get("setup"):
                    exec(suite["setup"], env)
                test = parser.get_doctest(case["code"], env, name, None, 0)
                runner.run(test, clear_globs=False)
                if runner.failure is not None:
                    return CheckOutcome(name, False, runner.failure)
        result = env.get("_r")
        message = getattr(result, "message", "") if result is not None else ""
        return CheckOutcome(name, True, message)

    def check_all(self, global_env: dict | None = None) -> list[CheckOutcome]:
        """Run every check of the worksheet (in its metadata's order)."""
        env = global_env if global_env is not None else inspect.currentframe().f_back.f_globals
        return [self.check(n, env) for n in self.tests]
