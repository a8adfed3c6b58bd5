"""Live plots of the rig's runs: the figure is redrawn as the telemetry arrives.

Every run of the rig client (:meth:`~jerklab.rig.Rig.step`, :meth:`~jerklab.rig.Rig.record_prbs`,
:meth:`~jerklab.rig.Rig.run_move`, the host loop of :meth:`~jerklab.rig.Rig.realtime` and
:meth:`~jerklab.rig.Rig.host_loop`) shows, inside a Jupyter kernel (JupyterLab, Notebook,
Voilà), one figure under its progress bar: position (and the reference) in rad over time in
s on top, voltage in V below (a PRBS's commanded voltage with it), with a label
``"<n>/<total> samples"`` that ends as ``"<n> samples (<status>)"``, ``n`` the length of the
recording. Pass ``live=False`` to the run (or to :func:`jerklab.rig.connect`) for none;
``$JERKLAB_LIVE_PLOT=0`` turns off the default (runs that pass ``live=True`` still plot).

Design choices
--------------
* The figure is a plain :class:`matplotlib.figure.Figure` drawn with the Agg canvas (no
  pyplot, so a user's figures are not touched), its PNG put into an :class:`ipywidgets.Image`,
  the same way as the tuning panels of :mod:`jerklab.widgets`. ipywidgets is already a
  dependency and its Image renders alike in JupyterLab, Notebook and Voilà; ipympl would add a
  front-end extension to every server and draws with Agg anyway, and bqplot a second plotting
  library beside matplotlib.
* The axes are drawn once, before the run starts, into a cached background; a redraw
  restores it and draws the curves only (blitting: milliseconds, where a full draw takes a
  tenth of a second or more), unless a value axis has to widen.
* Redraws run in a background thread, at most every :attr:`LivePlot.interval` = 0.125 s
  (8 a second; at least 5 while a redraw takes under 0.2 s), so the thread that reads the rig
  only appends samples: a host-in-the-loop law keeps its deadlines. The run thread never
  waits for a redraw; :meth:`LivePlot.close` stops the thread and draws the final figure with
  every sample of the recording (nothing is lost: the figure reads the recording itself).
* The time axis spans the whole run from the start (its length is known), so the curves grow
  from left to right; the value axes widen to 1-2-5 steps as the data need, never narrow.
* Headless execution (nbclient, nbconvert) has a kernel but no widget front end: at the end
  the display is updated with a bundle holding both the widget view and an ``image/png`` of
  the final figure, so a saved notebook keeps the final plot where no widget renders.
* Outside a kernel (a script, a terminal) nothing is drawn: the text progress bar stays.
* The tuning panel's button puts a run's plot in the panel's own box (``live_display`` of its
  rig), since a widget callback has no cell output to draw into: a rig connected in the page's
  kernel (a :class:`~jerklab.rig.Rig`: ``jerklab app`` without ``--rig``) fills the plot's
  recording as the telemetry arrives; the class page's shared rig
  (:class:`jerklab.broker.BrokerRig`, ``jerklab app --rig``) fills an in-memory recording with
  the batches of samples its broker streams during the run (at most 10 a second), then with
  the rest of the final recording, so the plot is the same.

Costs measured on the (loaded, 2-core) development machine, ``dpi=72``: a full draw of the
figure 0.3-0.5 s, a blitted redraw with its PNG 20-90 ms.
"""

from __future__ import annotations

import base64
import io
import math
import os
import threading
import time

import numpy as np

from jerklab.rig.progress import NoProgress, in_jupyter_kernel

__all__ = ["LivePlot", "live_plot", "Tee", "nice_limit"]

#: the DOM classes of the plot's box and its sample-count label (the browser tests find them)
BOX_CLASS = "jerklab-liveplot"
COUNT_CLASS = "jerklab-liveplot-count"


def nice_limit(x: float) -> float:
    """The smallest 1-2-5 value (…, 0.1, 0.2, 0.5, 1, 2, 5, …) that is ≥ ``|x|`` (> 0)."""
    x = abs(float(x))
    if not math.isfinite(x) or x <= 0:
        return 1.0
    e = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        v = m * 10.0**e
        if v >= x * (1 - 1e-12):
            return v
    return 10.0 ** (e + 1)  # pragma: no cover (m = 10 always qualifies)


def _range(lo_hi, data):
    """Widen ``(lo, hi)`` to hold ``data`` (each end that moves goes to a 1-2-5 value with a
    quarter of headroom, so that a growing curve widens it rarely); None if it holds them."""
    lo, hi = lo_hi
    finite = data[np.isfinite(data)]
    if finite.size == 0:
        return None
    dmin, dmax = float(finite.min()), float(finite.max())
    if lo <= dmin and dmax <= hi:
        return None
    if dmax > hi:
        hi = nice_limit(1.25 * dmax) if dmax > 0 else 0.0
    if dmin < lo:
        lo = -nice_limit(1.25 * dmin) if dmin < 0 else 0.0
    if lo >= hi:
        hi = lo + 1.0
    return lo, hi


def _start_range(hint):
    """The first ``(lo, hi)`` of an axis from the largest value expected (signed: a position
    that goes one way gets a tenth of the span the other way), ±1 without one."""
    if hint is None or not math.isfinite(float(hint)) or float(hint) == 0.0:
        return -1.0, 1.0
    span = nice_limit(1.1 * abs(float(hint)))
    return (-0.1 * span, span) if hint > 0 else (-span, 0.1 * span)


class Tee:
    """A progress bar and a live plot (or any objects with ``update(n)`` and
    ``close(note)``) driven as one."""

    def __init__(self, *parts):
        self.parts = parts

    def update(self, n):
        for p in self.parts:
            p.update(n)

    def close(self, note=""):
        for p in self.parts:
            p.close(note)


class LivePlot:
    """The live figure of one run, fed with the count of samples in its recording.

    Parameters
    ----------
    rec : jerklab.rig.Recording
        The recording being filled (the figure reads ``time``, ``reference``, ``position``
        and ``voltage`` from it; only appended rows are read, so another thread may append).
    total : int
        Samples expected (sets the time axis: ``total * rec.Ts`` s).
    label : str
        Name of the run (the figure's title), e.g. ``"virtual move"``.
    reference : {"rad", "V", None}
        Where the recording's ``reference`` goes: with the position (rad), with the voltage
        (V: a PRBS's commanded voltage) or nowhere (an open-loop step).
    live : bool
        Redraw during the run (every :attr:`interval` at most); False draws only the final
        figure, on :meth:`close`.
    widget : bool
        Show the figure as an ipywidgets Image with a sample-count Label; False keeps it in
        :attr:`png` only (tests, a caller that shows it itself).
    background : bool
        Redraw in a background thread (the default); False redraws inside :meth:`update` when
        the interval has passed (deterministic, with ``clock``).
    display : callable, optional
        Shows the widget (default: IPython's display with a display id); what it returns, if it
        has ``update(bundle, raw=True)`` (an IPython DisplayHandle), is given the end bundle.
    clock : callable
        Monotonic time in s (a fake one in tests).
    dpi : float
        Resolution of the PNG.
    position_range, voltage_range : float, optional
        The position (rad, signed: the move's distance) and the largest ``|voltage|`` (V)
        expected: the axes start there (rounded up to 1-2-5) and widen only if the data leave
        them (each widening costs a full draw of the figure).
    """

    #: seconds between two redraws during the run (at most 8 a second)
    interval = 0.125

    def __init__(
        self,
        rec,
        total,
        label,
        *,
        reference="rad",
        live=True,
        widget=True,
        background=True,
        display=None,
        clock=time.monotonic,
        dpi=72,
        position_range=None,
        voltage_range=None,
    ):
        if reference not in ("rad", "V", None):
            raise ValueError(f"reference must be 'rad', 'V' or None, got {reference!r}")
        if not callable(clock):
            raise TypeError(f"clock must be callable, got {clock!r}")
        self.rec = rec
        self.total = max(1, int(total))
        self.label = str(label)
        self.reference = reference
        self.live = bool(live)
        self.clock = clock
        self.draws = 0  # figures drawn (PNGs made)
        self.drawn_samples = []  # the sample count of each drawing
        self.draw_times = []  # the clock when each drawing was done
        self.n = 0  # samples reported by update()
        self.png = b""
        self.status = None
        self._next = -math.inf  # clock time of the next allowed redraw
        self._closed = False
        self._lock = threading.Lock()  # one drawing at a time
        self.full_draws = 0  # of them, full draws of the figure (the others blit the lines)
        self._build(dpi, position_range, voltage_range)
        self.widget = self.image = self.count = None
        self._handle = None
        if widget:
            self._show(display)
        if self.live:
            self._draw()  # the empty figure: its one full draw happens before the run starts
        self._stop = threading.Event()
        self._thread = None
        if self.live and background:
            self._thread = threading.Thread(
                target=self._run, name=f"jerklab live plot ({self.label})", daemon=True
            )
            self._thread.start()
        self._background = self._thread is not None

    # ------------------------------------------------------------------ figure
    def _build(self, dpi, position_range, voltage_range):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.fig = Figure(figsize=(7.0, 4.2), dpi=dpi, layout=None)
        FigureCanvasAgg(self.fig)
        self.ax_pos, self.ax_v = self.fig.subplots(2, 1, sharex=True)
        t_end = self.total * self.rec.Ts
        self.ax_pos.set_xlim(0.0, t_end if t_end > 0 else 1.0)
        self.ax_pos.set_ylabel("position (rad)")
        self.ax_v.set_ylabel("voltage (V)")
        self.ax_v.set_xlabel("time (s)")
        self.ax_pos.set_title(self.label, fontsize=10)
        (self.line_pos,) = self.ax_pos.plot([], [], color="C0", lw=1.2, label="position")
        (self.line_v,) = self.ax_v.plot([], [], color="C2", lw=1.0, label="voltage (applied)")
        self.line_ref = None
        if self.reference == "rad":
            (self.line_ref,) = self.ax_pos.plot(
                [], [], color="C1", lw=1.0, ls="--", label="reference"
            )
            self.ax_pos.legend(loc="upper left", fontsize=8)
        elif self.reference == "V":
            (self.line_ref,) = self.ax_v.plot(
                [], [], color="C1", lw=1.0, ls="--", label="voltage (commanded)"
            )
            self.ax_v.legend(loc="upper left", fontsize=8)
        self._ylim = {}
        v_hint = None if voltage_range is None else abs(float(voltage_range))
        for ax, lim in (
            (self.ax_pos, _start_range(position_range)),
            (self.ax_v, (-nice_limit(v_hint), nice_limit(v_hint)) if v_hint else (-1.0, 1.0)),
        ):
            self._ylim[ax] = lim
            ax.set_ylim(*lim)
            ax.grid(True, alpha=0.3)
        for line in self._lines():
            line.set_animated(True)
        self._background_image = None

    def _lines(self):
        return [x for x in (self.line_pos, self.line_ref, self.line_v) if x is not None]

    def _draw(self, final=False):
        """Put the recording's first ``len(rec)`` samples into the lines and make the PNG.

        The axes, ticks and labels are drawn once into a cached background (again only when an
        axis range widens); a redraw restores it and draws the lines (blitting), which takes
        milliseconds where a full draw of the figure takes a tenth of a second or more.
        """
        with self._lock:
            rec = self.rec
            n = len(rec)
            t = rec.time[:n]
            pos = rec.position[:n]
            volts = rec.voltage[:n]
            self.line_pos.set_data(t, pos)
            self.line_v.set_data(t, volts)
            pos_data, v_data = [pos], [volts]
            if self.line_ref is not None:
                ref = rec.reference[:n]
                self.line_ref.set_data(t, ref)
                (pos_data if self.reference == "rad" else v_data).append(ref)
            full = self._background_image is None
            for ax, data in ((self.ax_pos, pos_data), (self.ax_v, v_data)):
                new = _range(self._ylim[ax], np.concatenate(data)) if n else None
                if new is not None:
                    self._ylim[ax] = new
                    ax.set_ylim(*new)
                    full = True
            if final and n and t[-1] > self.ax_pos.get_xlim()[1]:
                self.ax_pos.set_xlim(0.0, float(t[-1]))
                full = True
            canvas = self.fig.canvas
            if full:
                canvas.draw()  # the lines are animated: not in the background
                self._background_image = canvas.copy_from_bbox(self.fig.bbox)
                self.full_draws += 1
            else:
                canvas.restore_region(self._background_image)
            for line in self._lines():
                line.axes.draw_artist(line)
            self.png = _png(canvas)
            self.draws += 1
            self.drawn_samples.append(n)
            self.draw_times.append(self.clock())
            if self.image is not None:
                self.image.value = self.png
                self.count.value = self._count_text(n)
            return n

    def _count_text(self, n):
        if self.status is None:
            return f"{n}/{self.total} samples"
        return f"{n} samples ({self.status})"

    def _show(self, display):
        import ipywidgets as w

        width = f"{round(self.fig.get_figwidth() * self.fig.dpi)}px"  # its own pixels, not blown up
        self.image = w.Image(format="png", layout=w.Layout(width=width, max_width="100%"))
        self.count = w.Label(self._count_text(0))
        self.count.add_class(COUNT_CLASS)
        self.widget = w.VBox([self.image, self.count])
        self.widget.add_class(BOX_CLASS)
        if display is None:
            from IPython.display import display as ipy_display

            handle = ipy_display(self.widget, display_id=True)
        else:
            handle = display(self.widget)
        self._handle = handle if callable(getattr(handle, "update", None)) else None

    # ------------------------------------------------------------------ feeding
    def _due(self) -> bool:
        now = self.clock()
        if now < self._next:
            return False
        self._next = now + self.interval
        return True

    def _run(self):
        drawn = 0
        while not self._stop.wait(0.02):
            if self.n != drawn and self._due():
                try:
                    drawn = self._draw()
                except Exception:  # a drawing error must not end the run: close() redraws
                    return

    def update(self, n):
        """The recording has ``n`` samples so far (absolute, not an increment)."""
        self.n = int(n)
        if self.live and not self._background and not self._closed and self._due():
            self._draw()

    def close(self, note=""):
        """Stop redrawing and draw the final figure with every sample; ``note`` is the run's
        status (``"complete"``, ``"timeout"``, ...), shown after the sample count."""
        if self._closed:
            return
        self._closed = True
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
        self.status = str(note) if note else "done"
        self._draw(final=True)
        if self._handle is not None:
            bundle = dict(self.widget._repr_mimebundle_())
            bundle["image/png"] = base64.b64encode(self.png).decode("ascii")
            self._handle.update(bundle, raw=True)


def _png(canvas) -> bytes:
    """The canvas as PNG, fast (zlib level 1: a third of the time of the default level)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(canvas.buffer_rgba())).save(buf, format="png", compress_level=1)
    return buf.getvalue()


#: environment variable that turns the default live plots off ("0", "off", "false", "no")
ENV = "JERKLAB_LIVE_PLOT"


def default_on() -> bool:
    """Whether runs without ``live=`` get a live plot: yes, unless ``$JERKLAB_LIVE_PLOT`` says
    ``0``/``off``/``false``/``no`` (e.g. a test suite that executes many notebooks headless)."""
    return os.environ.get(ENV, "").strip().lower() not in ("0", "off", "false", "no")


def live_plot(rec, total, label, enabled=None, *, reference="rad", display=None, **ranges):
    """The live plot of a run: a :class:`LivePlot` inside a Jupyter kernel that has
    ipywidgets, else an object that draws nothing.

    Parameters
    ----------
    rec, total, label, reference, display
        As for :class:`LivePlot`.
    enabled : bool or None
        True: a plot (in a kernel); False: none; None: as :func:`default_on` says.
    **ranges
        ``position_range``, ``voltage_range`` (see :class:`LivePlot`).

    Returns
    -------
    LivePlot or jerklab.rig.progress.NoProgress
        Either has ``update(n)`` and ``close(status)``.
    """
    if enabled is False or (enabled is None and not default_on()) or not in_jupyter_kernel():
        return NoProgress()
    try:
        import ipywidgets  # noqa: F401
    except ImportError:
        return NoProgress()
    return LivePlot(rec, total, label, reference=reference, display=display, **ranges)
