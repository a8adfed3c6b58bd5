"""Run a submitted worksheet and export its answers as plain JSON (inside the grading sandbox).

``python -m jerklab.lab.sheetrun NOTEBOOK FD NAME=VARIABLE ...`` executes every code cell of
``NOTEBOOK`` in one IPython shell (an error in a cell is noted and the next cell runs, as a
student's "Run all" with errors allowed), then writes one JSON document to the file
descriptor ``FD``::

    {"format": 1, "answers": {NAME: value}, "evidence": {...}, "errors": [...], "cells": n}

``answers`` holds the final value of each question's variable as :func:`export` gives it;
``evidence`` is the worksheet's :class:`~jerklab.lab.session.LabSession` evidence
(:meth:`jerklab.lab.plain.Evidence.to_dict`: its recordings' arrays and counts per
revolution), with ``claims`` and ``signatures``: the recordings that claim to come from the
class rig service and their signatures (:mod:`jerklab.lab.signing`), which the grader
verifies.

Nothing here is trusted: the process runs the student's code, which may change any of it.
The grader outside the sandbox (:mod:`jerklab.lab.grade`) reads only this JSON, decodes it
with :func:`jerklab.lab.grade.decode_answer` and scores it against the truth itself.
"""

from __future__ import annotations

import json
import math
import os
import sys

import numpy as np

from jerklab.controller import DiscreteGains
from jerklab.lab.session import LabSession
from jerklab.lab.signing import claims_graded

__all__ = ["export", "main"]

_MAX_DEPTH = 8


def export(x, depth=0):
    """``x`` as JSON data: numbers, strings, booleans, None, lists (from lists, tuples and numpy
    arrays), dicts with string keys, complex numbers as ``{"__jerklab__": "complex", "re",
    "im"}`` and :class:`jerklab.controller.DiscreteGains` as ``{"__jerklab__":
    "DiscreteGains", ...}``. Anything else becomes
    ``{"__jerklab__": "unsupported", "type": its type name}`` (the grader then says it cannot
    read the answer). ``...`` becomes None (no answer)."""
    if depth > _MAX_DEPTH:
        return {"__jerklab__": "unsupported", "type": "nested too deep"}
    if x is None or x is Ellipsis:
        return None
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else repr(v)
    if isinstance(x, (complex, np.complexfloating)):
        return {"__jerklab__": "complex", "re": export(x.real), "im": export(x.imag)}
    if isinstance(x, str):
        return str.__str__(x)
    if isinstance(x, np.ndarray):
        return [export(v, depth + 1) for v in np.asarray(x).tolist()]
    if isinstance(x, (list, tuple)):
        return [export(v, depth + 1) for v in x]
    if isinstance(x, dict):
        return {str(k): export(v, depth + 1) for k, v in x.items()}
    if isinstance(x, DiscreteGains):
        return {
            "__jerklab__": "DiscreteGains",
            "kpd": export(x.kpd),
            "kid": export(x.kid),
            "kdd": export(x.kdd),
            "Ts": export(x.Ts),
            "gamma": export(x.gamma),
            "loop": export(x.loop),
            "design": export(dict(x.design), depth + 1),
        }
    return {"__jerklab__": "unsupported", "type": type(x).__name__}


def _evidence(ns):
    sessions = [v for v in ns.values() if isinstance(v, LabSession)]
    if not sessions:
        return {}
    s = sessions[-1]
    doc = s.evidence().to_dict()
    # what each recording says of where it comes from: the grader verifies every one that
    # claims the class rig service (jerklab.lab.signing) and leaves out those that fail
    claims, sigs = {}, {}
    for name, rec in s.recordings.items():
        meta = getattr(rec, "metadata", None)
        if claims_graded(meta):
            claims[str(name)] = True
            sigs[str(name)] = export(meta.get("signature"))
    doc["claims"], doc["signatures"] = claims, sigs
    return doc


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    notebook, fd, pairs = argv[0], int(argv[1]), argv[2:]
    wanted = dict(p.split("=", 1) for p in pairs)
    with open(notebook, encoding="utf-8") as f:
        nb = json.load(f)
    from IPython.core.interactiveshell import InteractiveShell

    shell = InteractiveShell.instance()
    errors, cells = [], 0
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "code":
            continue
        src = cell.get("source", "")
        src = "".join(src) if isinstance(src, list) else str(src)
        cells += 1
        res = shell.run_cell(src, store_history=False, silent=False)
        exc = res.error_in_exec or res.error_before_exec
        if exc is not None and len(errors) < 20:
            errors.append({"cell": cells, "error": f"{type(exc).__name__}: {str(exc)[:200]}"})
    ns = shell.user_ns
    answers = {}
    for name, var in wanted.items():
        try:
            answers[name] = export(ns.get(var))
        except Exception as exc:  # a value whose conversion fails: no answer
            answers[name] = {"__jerklab__": "unsupported", "type": type(exc).__name__}
    try:
        evidence = _evidence(ns)
    except Exception as exc:
        evidence = {}
        errors.append({"cell": None, "error": f"recordings: {type(exc).__name__}"})
    doc = json.dumps(
        {"format": 1, "answers": answers, "evidence": evidence, "errors": errors, "cells": cells}
    ).encode()
    view = memoryview(doc)
    while view:
        n = os.write(fd, view)
        view = view[n:]
    os.close(fd)
    return 0


if __name__ == "__main__":
    sys.exit(main())
