"""One vocabulary for every time-series result, and the older names kept as aliases.

Every result that holds a run or a record (``jerklab.sim.SimResult``,
``jerklab.rig.Recording``, ``jerklab.ident.IdentData``, ...) names its series the same way:

============  =====  ===========================================================
name          unit   what
============  =====  ===========================================================
``time``      s      the sample instants
``reference`` rad    the reference the loop followed (where the result has one)
``position``  rad    the motor angle (each type says whether measured or true)
``velocity``  rad/s  the motor speed (where the result has one)
``voltage``   V      the voltage applied to the motor
============  =====  ===========================================================

A type that used other names before keeps them readable (and writable, unless the type is
frozen) through :func:`aliases`; :data:`ALIASES` lists every such name in one place, so the
reference documentation and a test can show them.
"""

from __future__ import annotations

__all__ = ["CANONICAL", "ALIASES", "aliases"]

#: the canonical series names, with their SI units
CANONICAL = {
    "time": "s",
    "reference": "rad",
    "position": "rad",
    "velocity": "rad/s",
    "voltage": "V",
}

#: ``{"module.Type": {"old name": "canonical name"}}`` for every type that keeps older names
ALIASES: dict[str, dict[str, str]] = {}


def _alias(old: str, new: str) -> property:
    def get(self):
        return getattr(self, new)

    def set_(self, value):
        setattr(self, new, value)

    return property(get, set_, doc=f"Older name of :attr:`{new}` (kept working).")


def aliases(**old_to_new: str):
    """Class decorator: make each ``old`` attribute name read and write ``new``.

    Parameters
    ----------
    **old_to_new : str
        ``old_name="new_name"`` pairs. ``new_name`` must be an attribute (a field or a
        property) of the class; ``old_name`` must not be one already.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @aliases(t="time")
    ... @dataclass
    ... class Run:
    ...     time: list
    >>> Run([0.0, 0.1]).t
    [0.0, 0.1]
    """

    def decorate(cls):
        fields = set(getattr(cls, "__dataclass_fields__", ()))
        for old, new in old_to_new.items():
            if not (new in fields or hasattr(cls, new)):
                raise TypeError(f"{cls.__name__}.{new} does not exist: cannot alias {old!r} to it")
            if old in fields or old in cls.__dict__:
                raise TypeError(f"{cls.__name__}.{old} already exists: it cannot become an alias")
            setattr(cls, old, _alias(old, new))
        ALIASES[f"{cls.__module__}.{cls.__qualname__}"] = dict(old_to_new)
        return cls

    return decorate
