"""Signed recordings: what the class rig service served, as the grader can check it.

The class rig service (:mod:`jerklab.lab.service`) signs every recording it serves; the grader
(:mod:`jerklab.lab.grade`) verifies the signature of every recording that claims to come from
the service (its ``signature``, or ``"mode": "graded"`` in its caller's fields) in a hand-in
and in a worksheet's export. A recording a student made or changed cannot carry a valid
signature: the key is the instructor's, which only the service and the grader hold.

The signature is HMAC-SHA256 (RFC 2104) with a key derived from the instructor key (an HMAC of
a fixed label, so that the motors' seeds and the signatures never share a key) over

    ``jerklab-recording-1`` NL ``{"lab", "student", "time"}`` NL canonical bytes

where the canonical bytes are the recording's arrays as the checks see them
(:class:`jerklab.lab.plain.Run`: time, reference, position, voltage, flags, Ts, kind) as
compact JSON with sorted keys; a float is written by ``repr``, so the bytes survive a CSV
round trip and the JSON export of a sandbox unchanged. The signature travels in the
recording's metadata (its JSON sidecar) under ``"signature"``: ``{"format", "student",
"lab", "time", "mac"}``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import hmac
import json

from jerklab.lab.plain import Run

__all__ = ["FORMAT", "canonical_bytes", "claims_graded", "sign_run", "verify_run"]

#: The signature's format (also the first line of the signed message).
FORMAT = "jerklab-recording-1"
_LABEL = b"jerklab recording signatures v1"


def _signing_key(key: bytes) -> bytes:
    if not isinstance(key, (bytes, bytearray)) or not key:
        raise ValueError("key must be the instructor key (non-empty bytes)")
    return hmac.new(bytes(key), _LABEL, hashlib.sha256).digest()


def canonical_bytes(run: Run) -> bytes:
    """The bytes of ``run`` a signature covers: its arrays, Ts and kind as compact JSON with
    sorted keys (floats by ``repr``)."""
    if not isinstance(run, Run):
        raise TypeError(f"run must be a jerklab.lab.plain.Run, got {type(run).__name__}")
    return json.dumps(run.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False).encode(
        "ascii"
    )


def _message(run: Run, student: str, lab: int, time: str) -> bytes:
    head = json.dumps(
        {"lab": int(lab), "student": str(student), "time": str(time)},
        sort_keys=True,
        separators=(",", ":"),
    )
    return FORMAT.encode() + b"\n" + head.encode("utf-8") + b"\n" + canonical_bytes(run)


def sign_run(key: bytes, run: Run, student: str, lab: int, time: str | None = None) -> dict:
    """The signature of ``run`` served to ``student`` in ``lab`` at ``time`` (default now, UTC,
    ISO 8601): ``{"format", "student", "lab", "time", "mac"}`` (``mac`` in hex)."""
    if time is None:
        time = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    mac = hmac.new(_signing_key(key), _message(run, student, lab, time), hashlib.sha256)
    return {
        "format": FORMAT,
        "student": str(student),
        "lab": int(lab),
        "time": str(time),
        "mac": mac.hexdigest(),
    }


def verify_run(key: bytes, run: Run, signature, student: str, lab: int) -> str | None:
    """None when ``signature`` is the service's for exactly ``run``, ``student`` and ``lab``;
    otherwise why not (no signature; not this format; another student's or lab's; the
    samples, Ts or kind differ from what was signed)."""
    if signature is None:
        return "no signature (not served by the class rig)"
    if not isinstance(signature, dict) or signature.get("format") != FORMAT:
        return "not a jerklab recording signature"
    mac, when = signature.get("mac"), signature.get("time")
    if not isinstance(mac, str) or not isinstance(when, str):
        return "not a jerklab recording signature"
    if str(signature.get("student")) != str(student):
        return "signed for another student"
    if signature.get("lab") != int(lab):
        return "signed for another lab"
    try:
        want = hmac.new(_signing_key(key), _message(run, student, lab, when), hashlib.sha256)
    except (TypeError, ValueError):
        return "not a jerklab recording signature"
    if not hmac.compare_digest(want.hexdigest(), mac):
        return "the signature does not match its samples (edited or made elsewhere)"
    return None


def claims_graded(metadata) -> bool:
    """True when a recording's metadata says it comes from the class rig service: it has a
    signature, or its caller's mode is ``"graded"``."""
    if not isinstance(metadata, dict):
        return False
    caller = metadata.get("caller")
    mode = caller.get("mode") if isinstance(caller, dict) else None
    return metadata.get("signature") is not None or mode == "graded"
