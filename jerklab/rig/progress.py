"""Progress bars of the rig's runs, drawn by tqdm (the replacement of the hand-written bars).

What the user sees is what ``jerklab.rig.client`` shows today:

* inside a Jupyter kernel (JupyterLab, Notebook, Voilà, nbclient) with ipywidgets: a widget
  bar (``tqdm.notebook``: a label with the run's name, the bar, and
  ``"<n>/<total> samples, <t> s"``), green when the run completes, red when it ends early;
* in a terminal (or a kernel without ipywidgets): a one-line text bar
  ``"<label> [#####....] <n>/<total> samples <t> s"`` ending with the status;
* nothing at all with ``enabled=False``.

The bars are redrawn at most ``1 / min_interval`` = 10 times a second (the last count is
always drawn on :meth:`TqdmProgress.close`), so a fast run is not slowed by its bar. Where
the text goes to a log rather than a terminal (output not a TTY, outside a kernel), only the
first and the final state are written: no carriage-return spam in CI logs.

tqdm.auto makes the same widget-or-text choice, but once, when it is imported; here it is
made per run with :func:`in_jupyter_kernel`, so a script that starts IPython later, or a
test, gets the right bar.

Usage (the rig client calls ``bar.update(samples_so_far)`` after every read and
``bar.close(status)`` at the end)::

    bar = progress(total, f"{port} move", enabled=True)
    ...
    bar.update(len(rec))
    bar.close("complete")
"""

from __future__ import annotations

import math
import sys

__all__ = ["NoProgress", "TqdmProgress", "progress", "in_jupyter_kernel"]

#: width of the text bar, characters
TEXT_BAR_WIDTH = 25


def in_jupyter_kernel() -> bool:
    """True inside a Jupyter kernel (JupyterLab, Notebook, Voilà, nbclient), not in a terminal.

    Looks only at an IPython that is already imported (a kernel always has one), so a plain
    ``python`` script does not pay for importing IPython.
    """
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    try:
        shell = ipython.get_ipython()
    except Exception:
        return False
    return shell is not None and getattr(shell, "kernel", None) is not None


def _display(widget) -> None:
    from IPython.display import display

    display(widget)


class NoProgress:
    """``progress=False``: no output at all."""

    kind = "none"

    def update(self, n):
        pass

    def close(self, note=""):
        pass


def _counting(base):
    """``base`` (a tqdm class) counting its redraws in ``draws``."""

    class _Bar(base):
        draws = 0

        def display(self, *args, **kwargs):
            self.draws += 1
            return super().display(*args, **kwargs)

    _Bar.__name__ = _Bar.__qualname__ = f"Counting{base.__name__}"
    return _Bar


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class TqdmProgress:
    """A tqdm bar over the samples of one run; ``update(n)`` takes the count so far.

    Parameters
    ----------
    total : int
        Samples expected (at least 1 is used).
    label : str
        Name of the run (e.g. ``"virtual move"``).
    widget : bool
        ``tqdm.notebook`` widget bar (needs ipywidgets; ImportError otherwise), else text.
    stream : file-like, optional
        Where the text bar goes (default ``sys.stdout``).
    display : callable, optional
        Shows the widget (default ``IPython.display.display``).
    live : bool, optional
        Redraw during the run (at most 10 times a second). Default: a widget, or a text
        stream that is a terminal; False writes the text bar only at the start and the end.
    clock : callable
        Monotonic time in s (tqdm's clock; a fake one in tests).
    """

    min_interval = 0.1

    def __init__(
        self, total, label, *, widget=False, stream=None, display=None, live=None, clock=None
    ):
        self.total = max(1, int(total))
        self.label = str(label)
        self.kind = "widget" if widget else "text"
        self.value = 0
        self._drawn = None
        stream = sys.stdout if stream is None else stream
        if live is None:
            live = widget or _isatty(stream)
        self.live = bool(live)
        common = dict(
            total=self.total,
            desc=self.label,
            miniters=1,
            leave=True,
            mininterval=self.min_interval if self.live else math.inf,
            maxinterval=0,
            smoothing=0,
        )
        if widget:
            from tqdm.notebook import IProgress
            from tqdm.notebook import tqdm as base

            if IProgress is None:  # tqdm found no ipywidgets
                raise ImportError("ipywidgets is needed for the widget progress bar")
            self._fmt = "{desc}<bar/>{n}/{total} samples, {elapsed_s:.1f} s"
            self._t = _counting(base)(bar_format=self._fmt, display=False, **common)
            self.widget = self._t.container
            label_w, self.bar, self.text = self.widget.children
            (display or _display)(self.widget)
        else:
            from tqdm.std import tqdm as base

            self._fmt = "{desc} [{bar:%d}] {n}/{total} samples {elapsed_s:5.1f} s" % TEXT_BAR_WIDTH
            self._t = _counting(base)(
                bar_format=self._fmt, file=stream, ascii=".#", dynamic_ncols=False, **common
            )
            self.stream = stream
        if clock is not None:  # before the first update: tqdm reads self._time
            self._t._time = clock
            self._t.start_t = self._t.last_print_t = clock()

    @property
    def draws(self) -> int:
        """Redraws so far (the initial one included)."""
        return self._t.draws

    def update(self, n):
        """The run has ``n`` samples so far (absolute, not an increment)."""
        n = min(int(n), self.total)
        self.value = n
        t = self._t
        if n == t.n:
            return
        if self._drawn is None and self.live:  # the first sample shows at once
            t.n = n
            t.refresh()
            t.last_print_n, t.last_print_t = n, t._time()
            self._drawn = n
            return
        t.update(n - t.n)
        if t.last_print_n == t.n:
            self._drawn = n

    def close(self, note=""):
        """Draw the last count with ``note`` (``"complete"``, ``"timeout"``, ...) and finish."""
        t = self._t
        if self.value != t.n:
            t.n = self.value
        if note:
            safe = str(note).replace("{", "{{").replace("}", "}}")
            t.bar_format = self._fmt + (f" ({safe})" if self.kind == "widget" else f" {safe}")
        self._drawn = t.n
        t.close()
        if self.kind == "widget" and note:
            self.bar.bar_style = "success" if note == "complete" else "danger"


def progress(total, label, enabled=True, *, stream=None, display=None):
    """The progress bar for a run: none (``enabled`` False), the tqdm widget inside a Jupyter
    kernel that has ipywidgets, the tqdm text bar otherwise."""
    if not enabled:
        return NoProgress()
    if in_jupyter_kernel():
        try:
            return TqdmProgress(total, label, widget=True, display=display)
        except ImportError:
            pass
    return TqdmProgress(total, label, stream=stream, live=True if in_jupyter_kernel() else None)
