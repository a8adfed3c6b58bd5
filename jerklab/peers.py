"""Peer libraries that jerklab measures itself against (optional dependencies).

Ruckig (https://github.com/pantor/ruckig) computes the time-optimal jerk-limited move; its
duration is the yardstick of the planners (notebook 01, ``benchmarks/bench_planner.py``).
Ruckig is optional: it is imported only when a function here is called, and a missing
install raises an :class:`ImportError` that says how to get it.
"""

from __future__ import annotations

from jerklab._validate import as_positive, as_real

__all__ = ["ruckig_duration", "ruckig_trajectory"]

_HINT = (
    "ruckig is not installed; it is optional and only needed for the comparison with the "
    "time-optimal jerk-limited planner: pip install 'ruckig>=0.12' (in environment.txt, "
    "and the 'test' extra of pyproject.toml)"
)


def _ruckig():
    try:
        import ruckig
    except ImportError as exc:
        raise ImportError(_HINT) from exc
    return ruckig


def ruckig_trajectory(distance, max_jerk, max_accel, max_velocity):
    """Ruckig's time-optimal rest-to-rest trajectory over ``distance`` (one degree of freedom).

    Parameters
    ----------
    distance : float
        Signed move length (rad, or any unit the limits share).
    max_jerk, max_accel, max_velocity : float
        Limits (> 0), in the units of ``distance`` per s³, s², s.

    Returns
    -------
    ruckig.Trajectory
        ``.duration`` (s) and ``.at_time(t)`` → (position, velocity, acceleration) lists.

    Raises
    ------
    ImportError
        If ruckig is not installed (with the command that installs it).
    RuntimeError
        If Ruckig does not return ``Result.Working`` (e.g. limits outside its numeric range).
    """
    d = as_real("distance", distance)
    J = as_positive("max_jerk", max_jerk)
    A = as_positive("max_accel", max_accel)
    V = as_positive("max_velocity", max_velocity)
    ruckig = _ruckig()
    otg, inp, traj = ruckig.Ruckig(1), ruckig.InputParameter(1), ruckig.Trajectory(1)
    inp.current_position, inp.target_position = [0.0], [d]
    inp.max_jerk, inp.max_acceleration, inp.max_velocity = [J], [A], [V]
    res = otg.calculate(inp, traj)
    if res != ruckig.Result.Working:
        raise RuntimeError(
            f"ruckig could not plan distance={d!r} with max_jerk={J!r}, "
            f"max_accel={A!r}, max_velocity={V!r}: {res}"
        )
    return traj


def ruckig_duration(distance, max_jerk, max_accel, max_velocity) -> float:
    """Duration (s) of Ruckig's time-optimal jerk-limited rest-to-rest move.

    The lower bound on the duration of any profile with ``|j| <= max_jerk``,
    ``|a| <= max_accel``, ``|v| <= max_velocity``; ``jerklab.planner.plan_scurve`` has the
    same duration (tests/test_planner.py). Arguments and errors as :func:`ruckig_trajectory`.
    """
    return float(ruckig_trajectory(distance, max_jerk, max_accel, max_velocity).duration)
