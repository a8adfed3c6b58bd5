"""The metrics of a move: one definition for the simulation, the rig and the lab worksheets.

:func:`move_metrics` reads a run by the series names of :mod:`jerklab._vocab` (``time``,
``reference``, ``position``, ``voltage`` and, where the run has it, ``saturated``), so the same
call measures a :class:`jerklab.sim.SimResult` (true motor angle), a
:class:`jerklab.rig.Recording` (encoder angle) or the plain data a lab check is given. With ``T``
the move's duration, ``D`` its distance, ``b`` the settle band, ``e = reference − position``:

======================  =====  ==============================================================
key                     unit   definition
======================  =====  ==============================================================
``max_error``           rad    max ``|e|`` during the move (``t <= T``): the tracking error a
                               spec limits
``peak_error``          rad    max ``|e|`` over the whole run (move and settle)
``rms_error``           rad    RMS of ``e`` during the move
``final_error``         rad    ``e`` at the last sample
``overshoot_pct``       %      ``max(0, max((position − D)·sign D))`` after the move, in % of
                               ``|D|`` (NaN for ``D = 0``)
``settling_time``       s      after the end of the move, until the position stays within
                               ``±b`` of ``D``: ``t_last + Ts − T`` for the last sample outside
                               the band (0 if it is inside by the end of the move, ``inf`` if
                               the last sample is outside)
``settle_band``         rad    ``b``
``peak_voltage``        V      max ``|voltage|`` over the run
``saturated``           —      samples with the saturation flag (runs that have one)
``saturated_fraction``  —      ``saturated`` / samples
======================  =====  ==============================================================

A sample that is not finite (a run that blew up) makes the errors it enters ``inf`` and the
settling time NaN. The arrays may carry a leading axis (many plants at once,
:func:`jerklab.sim.simulate_batch`): every value is then an array over it.

Older key names stay readable through :class:`MoveMetrics` (:data:`OLD_KEYS`, also listed in
``jerklab._vocab.ALIASES``): ``max_abs_error`` (now ``peak_error``), ``max_abs_voltage``
(``peak_voltage``), ``settling_band`` (``settle_band``).
"""

from __future__ import annotations

import numpy as np

from jerklab import _vocab
from jerklab._validate import as_finite_array, as_nonnegative, as_positive, as_real

__all__ = ["move_metrics", "series_metrics", "MoveMetrics", "KEYS", "OLD_KEYS"]

#: the keys every move's metrics have (``saturated`` and ``saturated_fraction`` where the run
#: has a saturation flag)
KEYS = (
    "max_error",
    "peak_error",
    "rms_error",
    "final_error",
    "overshoot_pct",
    "settling_time",
    "settle_band",
    "peak_voltage",
    "saturated",
    "saturated_fraction",
)
#: older name -> key (read through :class:`MoveMetrics`; iteration shows only the keys)
OLD_KEYS = {
    "max_abs_error": "peak_error",
    "max_abs_voltage": "peak_voltage",
    "settling_band": "settle_band",
}
_vocab.ALIASES["jerklab.metrics.MoveMetrics"] = dict(OLD_KEYS)


class MoveMetrics(dict):
    """A dict of move metrics (:data:`KEYS`) in which an older key name (:data:`OLD_KEYS`)
    reads its new key; ``dict(m)``, iteration and JSON show the new keys only."""

    def __missing__(self, key):
        new = OLD_KEYS.get(key)
        if new is not None and dict.__contains__(self, new):
            return dict.__getitem__(self, new)
        raise KeyError(key)

    def __contains__(self, key):
        return dict.__contains__(self, key) or (
            key in OLD_KEYS and dict.__contains__(self, OLD_KEYS[key])
        )

    def get(self, key, default=None):
        return self[key] if key in self else default


def _scalar(x):
    return float(x) if np.ndim(x) == 0 else x


def series_metrics(
    time, reference, position, voltage, duration, distance, *, settle_band, saturated=None
) -> MoveMetrics:
    """:func:`move_metrics` of the arrays of a run (the last axis is time).

    Parameters
    ----------
    time : (n,) array
        Sample instants (s), evenly spaced from the start of the move.
    reference, position : (n,) or (m, n) arrays
        Position reference and position (rad); ``position`` may hold ``m`` runs.
    voltage : (n,) or (m, n) array
        The voltage applied to the motor (V).
    duration, distance : float
        The move's duration (s, >= 0) and distance (rad; 0, a hold, has no overshoot_pct:
        NaN).
    settle_band : float
        Half-width of the settling band around ``distance`` (rad, > 0).
    saturated : (n,) or (m, n) bool array, optional
        The saturation flag of each sample.
    """
    t = as_finite_array("time", time, ndim=1)
    n = t.size
    if n == 0:
        raise ValueError("time must hold at least one sample")
    T = as_nonnegative("duration", duration)
    D = as_real("distance", distance)
    band = as_positive("settle_band", settle_band)
    r = np.asarray(reference, dtype=float)
    y = np.asarray(position, dtype=float)
    u = np.asarray(voltage, dtype=float)
    for name, a in (("reference", r), ("position", y), ("voltage", u)):
        if a.shape[-1:] != (n,):
            raise ValueError(f"{name} must have {n} samples (one per time), got shape {a.shape}")
    e = r - y
    ae = np.where(np.isfinite(e), np.abs(e), np.inf)
    during = t <= T + 1e-9
    after = ~during
    Ts = float(t[1] - t[0]) if n > 1 else 0.0
    none = np.zeros(e.shape[:-1])
    with np.errstate(invalid="ignore", over="ignore"):
        out = MoveMetrics(
            max_error=_scalar(np.max(ae[..., during], axis=-1) if during.any() else none),
            peak_error=_scalar(np.max(ae, axis=-1)),
            rms_error=_scalar(
                np.sqrt(np.mean(ae[..., during] ** 2, axis=-1)) if during.any() else none
            ),
            final_error=_scalar(e[..., -1]),
        )
        if D == 0.0:  # a hold (a disturbance test): no distance to take a percentage of
            out["overshoot_pct"] = _scalar(none + np.nan)
        elif after.any():
            over = np.max((y[..., after] - D) * np.sign(D), axis=-1)
            out["overshoot_pct"] = _scalar(np.maximum(0.0, over) / abs(D) * 100.0)
        else:
            out["overshoot_pct"] = _scalar(none)
        outside = ~(np.abs(D - y) <= band)  # NaN counts as outside
        any_out = outside.any(axis=-1)
        last = np.where(any_out, n - 1 - np.argmax(outside[..., ::-1], axis=-1), -1)
        settle = np.where(
            last < 0,
            0.0,
            np.where(last >= n - 1, np.inf, np.maximum(0.0, t[np.maximum(last, 0)] + Ts - T)),
        )
        settle = np.where(np.all(np.isfinite(y), axis=-1), settle, np.nan)
        out["settling_time"] = _scalar(settle)
        out["settle_band"] = band
        au = np.abs(u)
        out["peak_voltage"] = _scalar(
            np.max(np.where(np.isnan(au), -np.inf, au), axis=-1).clip(min=0.0)
        )
    if saturated is not None:
        s = np.asarray(saturated, dtype=bool)
        if s.shape[-1:] != (n,):
            raise ValueError(f"saturated must have {n} samples, got shape {s.shape}")
        count = np.count_nonzero(s, axis=-1)
        out["saturated"] = int(count) if np.ndim(count) == 0 else count
        out["saturated_fraction"] = _scalar(count / n)
    return out


def move_metrics(run, duration, distance, *, settle_band) -> MoveMetrics:
    """The metrics of one move (module docstring): ``run`` has ``time``, ``reference``,
    ``position``, ``voltage`` (and ``saturated`` if it has the flag).

    Parameters
    ----------
    run : SimResult, Recording or any object with those series
        A simulation measures the true motor angle, a recording the encoder's.
    duration, distance : float
        The move's duration (s) and distance (rad): ``profile.duration``, ``profile.distance``.
    settle_band : float
        Half-width (rad, > 0) of the band around ``distance`` that settling enters.

    Examples
    --------
    >>> from types import SimpleNamespace as Run
    >>> r = Run(time=[0.0, 0.1, 0.2, 0.3], reference=[0.0, 1.0, 1.0, 1.0],
    ...         position=[0.0, 0.8, 1.1, 1.0], voltage=[0.0, 3.0, -1.0, 0.0])
    >>> m = move_metrics(r, duration=0.1, distance=1.0, settle_band=0.05)
    >>> round(m["max_error"], 6), round(m["overshoot_pct"], 6), round(m["settling_time"], 6)
    (0.2, 10.0, 0.2)
    """
    return series_metrics(
        run.time,
        run.reference,
        run.position,
        run.voltage,
        duration,
        distance,
        settle_band=settle_band,
        saturated=getattr(run, "saturated", None),
    )
