"""Lab 5's checks (jerklab.lab.ownlaw): the replay of candidate laws names the law a host-loop run
applied (virtual rig, device clock frozen); the pre-lab checks and their mistakes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jerklab.controller import pole_placement_pid
from jerklab.lab import ownlaw as o
from jerklab.lab.plain import Evidence, Run
from jerklab.planner import plan_sine_jerk
from jerklab.rig import connect


class _StudentLaw:
    """Stojcic eqs. 16-18 written out (not jerklab.law), with a mistake on demand."""

    def __init__(self, g, ff, limit, mistake=None):
        self.g, self.ff, self.limit, self.mistake = g, ff, limit, mistake
        self.i = self.e = 0.0

    def __call__(self, t, y, r):
        g, m = self.g, self.mistake
        kid, kdd = (g.kid / g.Ts, g.kdd * g.Ts) if m == "continuous" else (g.kid, g.kdd)
        e = (y - r) if m == "sign" else (r - y)
        i = self.i + kid * e
        u = self.ff[round(t / g.Ts)] + g.kpd * e + i + kdd * (e - self.e)
        push = (u > self.limit and e < 0) if m == "aw_reversed" else (u > self.limit and e > 0)
        if push or (u < -self.limit and e < 0):
            u, i = u - kid * e, self.i
        self.i, self.e = i, e
        return min(max(u, -self.limit), self.limit)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    rig = connect(recordings=tmp_path_factory.mktemp("ownlaw"), progress=False)
    rig.link.device.clock = lambda: 0.0  # no late answer from a loaded machine
    K, tau = rig.model
    prof = plan_sine_jerk(2 * math.pi, 500.0, 40.0, 10.0)
    g = pole_placement_pid(K, tau, 10.0).discretize(o.TS5)
    board = rig.run_move(prof, g, Ts=o.TS5, settle=0.5, path=False, live=False)
    n = len(board)
    ff = o.feedforward_table(prof, n, o.TS5, K, tau)
    out = {"board": board}
    for m in (None, "sign", "continuous"):
        out[m or "pid"] = rig.host_loop(
            _StudentLaw(g, ff, 12.0, m),
            Ts=o.TS5,
            duration=(n - 1) * o.TS5,
            reference=prof,
            max_misses=255,
            max_error=0.0,
            live=False,
        )
    rig.close()
    law = dict(kpd=g.kpd, kid=g.kid, kdd=g.kdd, Ts=g.Ts, K=K, tau=tau, limit=12.0)
    return {k: Run.from_recording(r) for k, r in out.items()}, law, g, ff


@pytest.mark.parametrize("mistake", ["pid", "sign", "continuous"])
def test_diagnose_names_the_law_the_run_applied(runs, mistake):
    r, law, g, ff = runs
    name, rms = o.diagnose(r[mistake], o._ff_of(r[mistake], law["K"], law["tau"]), g, 12.0)
    assert name == mistake, (name, rms)
    # the exact feedforward replays the right law to within the PWM's rounding (12 V / 1023)
    exact, rms = o.diagnose(r[mistake], ff, g, 12.0, (mistake,))
    assert rms <= 12.0 / 1023


def test_match_passes_the_same_law_and_explains_a_wrong_sign(runs):
    r, law, _, _ = runs
    cpr = 448
    for mine, ok, words in [
        ("pid", True, "within"),
        ("sign", False, o.MISTAKES5["match_sign"].hint),
        ("continuous", False, o.MISTAKES5["match_continuous"].hint),
    ]:
        ev = Evidence(
            runs={"board": r["board"], "mine": r[mine]}, answers={"law": law}, counts_per_rev=cpr
        )
        apart = o._counts_apart(r[mine], r["board"], cpr)
        res = o.check_match(apart, ev, None)
        assert res.ok is ok and words in res.message, (mine, apart, res)
    # a measured distance that is not the recordings' own fails
    ev = Evidence(
        runs={"board": r["board"], "mine": r["pid"]}, answers={"law": law}, counts_per_rev=cpr
    )
    assert not o.check_match(40.0, ev, None)


def test_variant_pd_is_read_from_its_run(runs):
    r, law, g, ff = runs
    # (the P-only replay of the full-PID run is not the PID: the check says so)
    ev = Evidence(runs={"variant": r["pid"]}, answers={"law": law}, counts_per_rev=448)
    err = float(np.max(np.abs(r["pid"].reference - r["pid"].position)))
    assert o.check_variant({"law": "pd", "max_error": err}, ev, None).ok is False


@pytest.mark.parametrize(
    ("name", "answer", "ok", "words"),
    [
        ("pre_ff", (0.025 * 200 + 10) / 32.4, True, "u_F"),
        ("pre_ff", 10 / 32.4, False, o.MISTAKES5["pre_ff_no_accel"].hint),
        ("pre_delay", 10.0, True, "one whole tick"),
        ("pre_delay", 0.0, False, o.MISTAKES5["pre_delay_board"].hint),
    ],
)
def test_pre_lab(name, answer, ok, words):
    res = getattr(o, f"check_{name}")(answer, Evidence(), None)
    assert res.ok is ok and words in res.message


def test_check_law_takes_the_labs_design_and_names_the_continuous_gains():
    """check_law against pole_placement_pid's own discretization (Stojčić eqs. 11, 13) at the
    lab's ωn: the discrete gains pass, the continuous ones get their hint, Ts in ms is named."""
    from jerklab.lab.specs import lab_spec

    spec = lab_spec(5)
    K, tau = 30.0, 0.03
    g = pole_placement_pid(K, tau, spec["design_wn"], spec["zeta"])
    d = g.discretize(spec["Ts"])
    law = dict(kpd=d.kpd, kid=d.kid, kdd=d.kdd, Ts=spec["Ts"], K=K, tau=tau, limit=1.0)
    assert o.check_law(law, Evidence(), None).ok
    res = o.check_law({**law, "kid": g.ki, "kdd": g.kd}, Evidence(), None)
    assert not res.ok and o.MISTAKES5["law_continuous"].hint in res.message
    assert "not milliseconds" in o.check_law({**law, "Ts": 10.0}, Evidence(), None).message
    assert not o.check_law({**law, "kpd": 2 * d.kpd}, Evidence(), None).ok
    assert not o.check_law({**law, "limit": 13.0}, Evidence(), None).ok
    with pytest.raises(o.Missing, match="no 'limit'"):
        o.check_law({k: v for k, v in law.items() if k != "limit"}, Evidence(), None)


def test_the_class_rig_service_closes_a_students_law_through_the_hidden_motor(tmp_path):
    """Lab 5 on the hub: the class rig service runs the hidden motor in real time and sends each
    tick; the student's kernel (a :class:`ClassRig`) answers with its law's voltage. A P law
    on a 2 rad reference gets there (short by at most the friction over its gain); the
    recording is the service's, signed, with its misses, and kept by the service as the run the
    checks read; a law that raises stops the motor with
    its tick named; a ``realtime`` loop left early ends "stopped"; the lab's tracking stop
    cannot be raised; a lab without a host loop refuses the op."""
    import json

    from jerklab.lab.classrig import ClassRig
    from jerklab.lab.plain import Run
    from jerklab.lab.service import ClassRigService, TokenFile
    from jerklab.lab.signing import verify_run
    from jerklab.rig.hostloop import ControlLawError

    key = b"host-loop-service-test-key"
    tokens = tmp_path / "tokens.json"
    tokens.write_text(json.dumps({"tok-ann-0123456789": "ann"}))
    with ClassRigService(TokenFile(tokens), tmp_path / "log.jsonl", key=key) as svc:
        rig = ClassRig(svc.url, 5, token="tok-ann-0123456789")
        try:
            rec = rig.host_loop(
                lambda t, y, r: 1.0 * (r - y), Ts=0.01, duration=1.5, reference=2.0, name="p"
            )
            md = rec.metadata
            assert md["status"] == "complete", md["status"]
            # a P law stops short by at most the friction (<= 0.6 V) over its gain
            assert len(rec) == 151 and abs(rec.position[-1] - 2.0) < 0.6
            assert md["caller"]["mode"] == "graded" and md["hostloop"]["misses"] <= 5
            st = svc._students[("ann", 5)]
            assert verify_run(key, Run.from_recording(rec), md["signature"], "ann", 5) is None
            assert "p" in st.runs and np.array_equal(st.runs["p"].position, rec.position)

            def bad(t, y, r):
                if t > 0.2:
                    raise ZeroDivisionError("oops")
                return 1.0

            with pytest.raises(
                ControlLawError, match=r"ZeroDivisionError: oops at tick 2[01]"
            ) as e:
                rig.host_loop(bad, Ts=0.01, duration=1.0, name="bad")
            assert "ZeroDivisionError" in e.value.recording.metadata["status"]
            loop = rig.realtime(0.01, 1.0, name="early")
            for step in loop:
                step.apply(0.5)
                if step.index == 10:
                    break
            del step
            import gc

            gc.collect()  # the generator closed: the service stops the run
            assert loop.recording is not None
            assert loop.recording.metadata["status"].startswith("stopped"), loop.recording.metadata
            with pytest.raises(ValueError, match="max_error"):
                rig.host_loop(lambda t, y, r: 0.0, 0.01, 0.5, reference=1.0, max_error=100.0)
        finally:
            rig.close()
        lab3 = ClassRig(svc.url, 3, token="tok-ann-0123456789")
        try:
            with pytest.raises(ValueError, match="host-in-the-loop labs"):
                lab3.host_loop(lambda t, y, r: 0.0, 0.01, 0.5)
        finally:
            lab3.close()
