"""jerklab.lab.signing: HMAC-SHA256 signatures of recordings (checked against hashlib's HMAC)."""

from __future__ import annotations

import hashlib
import hmac
import json

import numpy as np
import pytest

from jerklab.lab.plain import Run
from jerklab.lab.signing import FORMAT, canonical_bytes, claims_graded, sign_run, verify_run

KEY = b"instructor-key-for-tests"


def _run(seed=0, n=50):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.005
    return Run(
        t, np.zeros(n), np.cumsum(rng.normal(size=n)), np.full(n, 6.0), np.zeros(n), 0.005, "step"
    )


def test_mac_is_rfc2104_hmac_over_the_documented_message():
    run = _run()
    sig = sign_run(KEY, run, "alice", 1, time="2026-12-02T10:00:00+00:00")
    k = hmac.new(KEY, b"jerklab recording signatures v1", hashlib.sha256).digest()
    head = json.dumps(
        {"lab": 1, "student": "alice", "time": "2026-12-02T10:00:00+00:00"},
        sort_keys=True,
        separators=(",", ":"),
    ).encode()
    body = json.dumps(run.to_dict(), sort_keys=True, separators=(",", ":")).encode()
    want = hmac.new(k, FORMAT.encode() + b"\n" + head + b"\n" + body, hashlib.sha256).hexdigest()
    assert sig["mac"] == want and sig["format"] == FORMAT
    assert canonical_bytes(run) == body


def test_verifies_its_own_and_survives_a_json_round_trip():
    run = _run()
    sig = sign_run(KEY, run, "alice", 2)
    again = Run.from_dict(json.loads(json.dumps(run.to_dict())))
    assert verify_run(KEY, again, json.loads(json.dumps(sig)), "alice", 2) is None


@pytest.mark.parametrize(
    "change, why",
    [
        ("value", "does not match"),
        ("kind", "does not match"),
        ("student", "another student"),
        ("lab", "another lab"),
        ("key", "does not match"),
        ("none", "no signature"),
        ("time", "does not match"),
    ],
)
def test_any_change_is_found(change, why):
    run = _run()
    sig = sign_run(KEY, run, "alice", 1)
    student, lab, key = "alice", 1, KEY
    if change == "value":
        d = run.to_dict()
        d["position"][17] += 1e-9
        run = Run.from_dict(d)
    elif change == "kind":
        d = run.to_dict()
        d["kind"] = "move"
        run = Run.from_dict(d)
    elif change == "student":
        student = "bob"
    elif change == "lab":
        lab = 2
    elif change == "key":
        key = b"a student's guess"
    elif change == "none":
        sig = None
    elif change == "time":
        sig = {**sig, "time": "2020-01-01T00:00:00+00:00"}
    assert why in verify_run(key, run, sig, student, lab)


def test_claims_graded_reads_signature_or_mode():
    assert claims_graded({"signature": {"mac": "x"}})
    assert claims_graded({"caller": {"mode": "graded"}})
    assert not claims_graded({"caller": {"mode": "practice"}})
    assert not claims_graded(None)
