"""Laws the mutation audit of issue 31 found unpinned, each checked against an independent
reference (numerical integration, an independent least squares, a frame built by hand, the
device's own limit from its fixed-point range).

Each test names the single-point mutant it kills; ``tests/faults/README.md`` lists them with the
run that showed each test failing with its mutant applied.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from jerklab import protocol as P
from jerklab.ident.arx import arx
from jerklab.multiaxis import stretch_to_duration
from jerklab.planner import plan_scurve, plan_sine_jerk_optimal


# ------------------------------------------------------------------ multi-axis time sync
def _integrated(profile, n=200_001):
    """Peak |acceleration| by integrating the sampled jerk, and the end velocity and position by
    integrating the sampled acceleration (trapezoidal rule): independent of the closed forms
    of the distance and of the peaks."""
    t = np.linspace(0.0, profile.duration, n)
    s = profile.sample(t)
    dt = t[1] - t[0]

    def integral(f):
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * dt)])

    a = integral(s.jerk)  # the peak acceleration from the jerk alone
    v = integral(s.accel)  # the end state from the (continuous) acceleration
    x = integral(v)
    return float(np.max(np.abs(a))), float(x[-1]), float(v[-1])


@pytest.mark.parametrize(
    "planner, jscale", [(plan_scurve, 1.0), (plan_sine_jerk_optimal, 2 / math.pi)]
)
@pytest.mark.parametrize("rel", [-0.05, -0.01, -1e-3, 1e-3, 1e-2, 0.05, 0.15])
def test_stretch_near_the_plateau_boundary_keeps_the_acceleration_limit(planner, jscale, rel):
    """Mutants killed: ``T <= d / (A tja) + 2 tja`` (multiaxis._stretch, the choice between the
    plateau and the no-plateau closed form) moved by one ``tja`` either way. Below the boundary
    the wrong (no-plateau) form stretches the axis past its acceleration limit; above it the
    wrong (plateau) form keeps full-length pulses at a lowered jerk, no longer the time-optimal
    profile of a lowered velocity limit."""
    J, A, V = 2000.0, 300.0, 100.0
    d = 50.0  # the optimum reaches V after a plateau at A: its duration is below the boundary
    p = planner(d, J, A, V)
    Jl = jscale * J
    tja = A / Jl
    boundary = d / (A * tja) + 2.0 * tja  # T(v = A^2/J): the plateau shrinks to nothing there
    assert p.duration < boundary * 0.95
    T = boundary * (1.0 + rel)
    q = stretch_to_duration(p, T)
    assert q.duration == pytest.approx(T, rel=1e-12)
    a_peak, x_end, v_end = _integrated(q)
    assert a_peak <= A * (1 + 1e-6), (rel, a_peak / A)
    assert x_end == pytest.approx(d, rel=1e-6) and abs(v_end) <= 1e-6 * d / T
    # the law of stretch_to_duration: the time-optimal profile for the same jerk and
    # acceleration limits and a lowered velocity limit -- re-planned by the single-axis planner
    # with the stretched axis's peak velocity as the limit, it lasts as long, at the full jerk
    r = planner(d, J, A, q.peak_velocity)
    assert r.duration == pytest.approx(T, rel=1e-9)
    assert q.peak_jerk == pytest.approx(J, rel=1e-9)
    # with a plateau below the boundary, the acceleration limit itself is reached
    if rel < 0:
        assert a_peak == pytest.approx(A, rel=1e-4)
    else:
        assert a_peak < A * (1 - 1e-4)


# ------------------------------------------------------------------ ARX noise variance
def test_arx_noise_variance_divides_by_the_degrees_of_freedom():
    """Mutant killed: ``dof = target.size`` instead of ``target.size - npar`` (ARX lambda).

    Against an independent least squares (numpy.linalg.lstsq on regressors built here) and the
    law E[SSR] = sigma^2 (N - p) for fixed regressors (a FIR model)."""
    rng = np.random.default_rng(31)
    N, nb, nk = 40, 3, 1
    u = rng.standard_normal(N)
    b = np.array([0.5, -0.3, 0.2])
    sigma = 0.1
    lams = []
    for _ in range(600):
        y = np.zeros(N)
        for k in range(N):
            y[k] = sum(b[i] * u[k - nk - i] for i in range(nb) if k - nk - i >= 0)
        y += sigma * rng.standard_normal(N)
        r = arx(y, u, 0, nb, nk)
        n0 = nk + nb - 1
        Phi = np.column_stack([u[n0 - nk - i : N - nk - i] for i in range(nb)])
        coef, *_ = np.linalg.lstsq(Phi, y[n0:], rcond=None)
        ssr = float(np.sum((y[n0:] - Phi @ coef) ** 2))
        n_eq = N - n0
        assert r.noise_variance == pytest.approx(ssr / (n_eq - nb), rel=1e-9)
        lams.append(r.noise_variance)
    # unbiased: the mean over 600 records is sigma^2 within 4 standard errors (the mutant's
    # (N - p) / N = 35/38 is 8 standard errors low)
    se = sigma**2 * math.sqrt(2.0 / (N - n0 - nb)) / math.sqrt(len(lams))
    assert abs(np.mean(lams) - sigma**2) < 4 * se


# ------------------------------------------------------------------ frame decoder
def _frame_by_hand(length_byte, msg_type, seq, payload):
    body = bytes((length_byte, msg_type, seq)) + payload
    return P.SYNC + body + struct.pack("<H", P._crc(body))


def test_decoder_refuses_a_length_just_past_the_maximum_payload():
    """Mutant killed: ``length > MAX_PAYLOAD + 2`` off by one (protocol.Decoder.feed).

    A frame built by hand with a valid CRC: the longest legal payload (64 bytes, len 66) is
    returned; one byte more (len 67) is not a frame even with its CRC right, and the good frame
    behind it is still found."""
    longest = _frame_by_hand(P.MAX_PAYLOAD + 2, 0x20, 7, bytes(range(P.MAX_PAYLOAD)))
    assert longest == P.encode_frame(0x20, 7, bytes(range(P.MAX_PAYLOAD)))  # the encoder agrees
    too_long = _frame_by_hand(P.MAX_PAYLOAD + 3, 0x20, 8, bytes(range(P.MAX_PAYLOAD + 1)))
    good = P.encode(P.Ack(9), 9)
    d = P.Decoder()
    frames = d.feed(longest + too_long + good)
    assert [(f.seq, len(f.payload)) for f in frames] == [(7, P.MAX_PAYLOAD), (9, 1)]
    assert d.stats.bad_length == 1
    with pytest.raises(P.ProtocolError, match="payload must be <= 64"):
        P.encode_frame(0x20, 8, bytes(P.MAX_PAYLOAD + 1))


# ------------------------------------------------------------------ client: stale replies
class _InjectingLink:
    """Passes everything through; after the next write, the device's reply is preceded by
    ``frames`` (bytes), as a late reply to an earlier request would be."""

    def __init__(self, link):
        self.link, self.pending, self.armed = link, b"", b""

    def __getattr__(self, name):
        return getattr(self.link, name)

    def write(self, data):
        self.pending, self.armed = self.armed, b""
        return self.link.write(data)

    @property
    def in_waiting(self):
        return len(self.pending) + self.link.in_waiting

    def read(self, size=1):
        if self.pending:
            out, self.pending = self.pending[:size], self.pending[size:]
            return out
        return self.link.read(size)


def _rig():
    from jerklab.plant import DCMotor
    from jerklab.rig import Rig, VirtualDevice, VirtualSerial

    link = VirtualSerial(VirtualDevice(DCMotor()), timeout=0.05)
    return Rig(link, "virtual", progress=False, timeout=1.0, hello_timeout=1.0)


def test_a_stale_reply_with_another_sequence_number_is_ignored():
    """Mutant killed: dropping ``f.seq == seq`` from the reply match (Rig._request): a late
    reply to an earlier request was taken for the answer to this one."""
    rig = _rig()
    try:
        real = rig.hello()
        inj = _InjectingLink(rig.link)
        rig.link = inj
        seq = rig._seq  # the next request's sequence number
        stale_reply = P.HelloReply(99, 0, 0, 0, 0, 4000, 255, "stale-board")
        inj.armed = P.encode(stale_reply, (seq - 1) & 0xFF)
        before = rig.ignored_frames
        got = rig.hello()
        assert got == real and got.name != "stale-board"
        assert rig.ignored_frames == before + 1
        # a stale NACK of another request does not fail this one
        inj.armed = P.encode(P.Nack(int(P.MsgType.STOP), 3, 0), (rig._seq + 5) & 0xFF)
        rig.stop()
        assert rig.ignored_frames == before + 2
    finally:
        rig.close()


# ------------------------------------------------------------------ client: RUN gain bound
@pytest.mark.parametrize("name", ["kpd", "kid", "kdd"])
def test_the_run_gain_bound_holds_for_negative_gains(name):
    """Mutant killed: ``abs(k) >= limit`` -> ``k >= limit`` (Rig.configure): a negative gain
    beyond the device's fixed-point range reached RUN, which refuses it without naming it.

    The bound from its definition (firmware/PROTOCOL.md): RUN_GAIN_LIMIT PWM ticks per encoder
    count, i.e. limit [V/rad] = 2**23 * (supply / pwm_max) * (counts_per_rev / 2 pi)."""
    from jerklab.controller import DiscreteGains
    from jerklab.rig import RunSpec

    rig = _rig()
    try:
        limit = (
            2.0**23 * (rig.supply_voltage / rig.info.pwm_max) * (rig.counts_per_rev / (2 * math.pi))
        )
        assert P.max_run_gain(
            rig.counts_per_rev, rig.info.pwm_max, rig.supply_voltage
        ) == pytest.approx(limit)
        base = dict(kpd=1.0, kid=0.1, kdd=0.5)
        for sign in (-1.0, 1.0):
            bad = DiscreteGains(**dict(base, **{name: sign * 1.01 * limit}), Ts=0.005)
            with pytest.raises(
                ValueError, match=rf"gains\.{name} = .* beyond what the device's PID"
            ):
                rig.configure(bad, RunSpec(Ts=0.005))
            ok = DiscreteGains(**dict(base, **{name: sign * 0.99 * limit}), Ts=0.005)
            rig.configure(ok, RunSpec(Ts=0.005))  # the device takes it (ACK)
    finally:
        rig.close()


# ------------------------------------------------------------------ lab: the friction check
def test_the_friction_check_tolerance_is_pinned():
    """Mutant killed: a wider (or narrower) ``tol`` in lab.checks.check_f_c. No test gave a
    wrong friction answer: an answer 0.06 V off passes, 0.061 V off fails, on either side, for
    the truth of a simulated plant (f_c = 0.3 V, offset 0.02 V)."""
    from jerklab.lab.checks import check_f_c

    truth = {"K": 30.0, "tau": 0.03, "coulomb_friction": 0.3, "offset": 0.02}
    for v, ok in [
        (0.3, True),
        (0.359, True),
        (0.241, True),
        (0.361, False),
        (0.239, False),
        (0.5, False),
        (0.0, False),
    ]:
        r = check_f_c(v, None, truth)
        assert r.ok is ok, (v, r)


# ------------------------------------------------------------------ lab: the hidden motor
def test_the_hidden_motor_derivation_is_pinned():
    """Mutants killed: any change to how a student's hidden motor is derived from the key and
    the ID (the HMAC message, the digest bytes and their order, the draws and their order),
    which before was pinned only through per-student outcomes.

    Reference: the derivation written out here from its description -- seed = the first 16
    bytes, little endian, of HMAC-SHA256(key, "jerklab:motor-v1:" + ID); then, from
    numpy's default_rng(seed), K and tau log-uniform, f_c, offset and the count noise uniform,
    the encoder 448 or 896 counts per revolution (lab.motors.RANGES)."""
    import hashlib
    import hmac

    from jerklab.lab.motors import RANGES, hidden_truth, student_motor

    key = b"a key for the test"
    for sid in ("alice", "s1234567", "j.doe@uni.edu"):
        m = hidden_truth(student_motor(f"  {sid.upper()} ", key))
        canon = sid.lower()
        digest = hmac.new(key, f"jerklab:motor-v1:{canon}".encode(), hashlib.sha256).digest()
        seed = int.from_bytes(digest[:16], "little")
        rng = np.random.default_rng(seed)
        K = math.exp(rng.uniform(math.log(RANGES["K"][0]), math.log(RANGES["K"][1])))
        tau = math.exp(rng.uniform(math.log(RANGES["tau"][0]), math.log(RANGES["tau"][1])))
        fc = rng.uniform(*RANGES["coulomb_friction"])
        off = rng.uniform(*RANGES["offset"])
        noise = rng.uniform(*RANGES["noise_counts"])
        ppr = int(rng.choice(RANGES["encoder_ppr"]))
        assert (m["K"], m["tau"], m["coulomb_friction"], m["offset"], m["noise_counts"]) == (
            K,
            tau,
            fc,
            off,
            noise,
        )
        assert m["counts_per_rev"] == ppr and m["seed"] == seed % 2**32
        # another key, another motor
        assert hidden_truth(student_motor(sid, b"another key"))["K"] != K


# ------------------------------------------------------------------ planner fast path
def test_the_written_out_phase_times_are_the_reference_ones():
    """plan_scurve and plan_sine_jerk_optimal write the phase times of planner._scurve_times
    out on their hot path (issue 31, speed): over the four regimes of the S-curve and its
    boundaries they give exactly the reference function's times."""
    from jerklab.planner import _TWO_OVER_PI, _scurve_times

    rng = np.random.default_rng(7)
    cases = [
        (
            10 ** rng.uniform(-3, 3),
            10 ** rng.uniform(1, 5),
            10 ** rng.uniform(0, 3),
            10 ** rng.uniform(-1, 2),
        )
        for _ in range(3000)
    ]
    J, A, V = 2000.0, 300.0, 100.0
    for d in (
        A**3 / J**2 * 2,
        V * (2 * A / J + V / A - A / J),
        2 * V * math.sqrt(V / J),
        1e-300,
        1e300,
    ):
        cases.append((d, J, A, V))
    for d, J, A, V in cases:
        for sign in (1.0, -1.0):
            p = plan_scurve(sign * d, J, A, V)
            assert (p._tj, p._ta, p._tv) == _scurve_times(d, J, A, V)
            q = plan_sine_jerk_optimal(sign * d, J, A, V)
            assert (q._tj, q._ta, q._tv) == _scurve_times(d, _TWO_OVER_PI * J, A, V)


# ------------------------------------------------------------------ virtual rig: runaway edge
@pytest.mark.parametrize("pwm, stops", [(100, False), (101, True)])
def test_the_no_motion_threshold_at_an_odd_pwm_top(pwm, stops):
    """Mutant killed: ``P = (pwm_top + 1) div 2`` -> ``pwm_top div 2`` (VirtualDevice, PROTOCOL.md
    "Safety stops" 2), seen only at an odd ``pwm_top``.

    A stalled motor (Coulomb friction far above the drive: the encoder never counts) and a
    proportional loop without feedforward: after the move the drive is ``kpd d``, a PWM held
    constant for the whole settle time. With ``max_voltage`` giving ``pwm_top = 201``,
    ``P = 101``: a held PWM of 100 is not a large drive and the run completes; 101 is, and the
    run ends NO_MOTION after ``runaway_time``."""
    from jerklab.controller import DiscreteGains
    from jerklab.planner import plan_trapezoid
    from jerklab.plant import DCMotor
    from jerklab.rig import RigRunError, connect

    supply, pwm_max, top = 12.0, 1023, 201
    max_voltage = top * supply / pwm_max
    assert math.floor(max_voltage * pwm_max / supply + 0.5) == top and top % 2 == 1
    d, Ts = 1.0, 0.005
    kpd = (pwm + 0.2) * supply / pwm_max / d  # lround(kpd d pwm_max / supply) == pwm
    motor = DCMotor(coulomb_friction=50.0)
    with connect(None, device=motor, progress=False) as rig:
        assert rig.info.pwm_max == pwm_max and rig.supply_voltage == supply
        run = dict(
            feedforward=False,
            max_voltage=max_voltage,
            max_error=0.0,
            runaway_time=0.2,
            saturation_time=0.0,
            settle=0.5,
            force=True,
            path=False,
        )
        prof = plan_trapezoid(d, 300.0, 100.0)
        gains = DiscreteGains(kpd, 0.0, 0.0, Ts)
        if stops:
            with pytest.raises(RigRunError) as e:
                rig.run_move(prof, gains, Ts, **run)
            rec = e.value.recording
            assert "no motion" in e.value.status or "no_motion" in e.value.status.lower()
        else:
            rec = rig.run_move(prof, gains, Ts, **run)
            assert rec.metadata["status"] == "complete"
        assert np.all(rec.counts == 0)  # stalled throughout
        held = rec.pwm[-int(0.2 / Ts) :] if not stops else rec.pwm[-5:-1]  # the stop sample: 0
        assert np.all(held == pwm)
