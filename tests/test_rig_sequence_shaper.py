"""SEQUENCE (an on-board PRBS) and SET_SHAPER of the serial protocol on the rig
(an input shaper as a FIR on the run reference) — the firmware core on the host (g++), the
virtual rig that mirrors it, the client (``Rig.record_prbs``, ``Rig.set_shaper``), and the
flexible load (``connect(device=FlexibleDCMotor())``, per-student hidden modes).

The simulated-Uno side (the firmware ELF on simavr) is in
tests/test_rig_sequence_shaper_simavr.py."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from jerklab import protocol as P
from jerklab.controller import discrete_pole_placement_pid, pole_placement_pid
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor, FlexibleDCMotor
from jerklab.rig import RigConnectionError, RigError, connect
from jerklab.rig.virtual import VirtualDevice, VirtualSerial

f32 = lambda x: float(np.float32(x))  # noqa: E731


def _host(driver):
    from test_firmware import HostDevice

    return HostDevice(driver)


def _virtual_talk(msgs, ticks=0, motor=None):
    """Send ``msgs`` to a VirtualDevice, run ``ticks`` control periods, return its messages."""
    # the host driver applies each PWM at its tick: no computation delay on either side
    dev = VirtualDevice(
        motor if motor is not None else DCMotor(), clock=lambda: 0.0, compute_delay=0.0
    )
    for i, m in enumerate(msgs):
        dev.receive(P.encode(m, i + 1))
    for _ in range(ticks):
        dev.tick()
    return [P.parse(f) for f in P.Decoder().feed(dev.read_output())]


# ----------------------------------------------------------------------------- parameter checks

BAD_SEQUENCES = [
    (P.Sequence(-1.0, 0.0, 5000, 10), 0),
    (P.Sequence(float("nan"), 0.0, 5000, 10), 0),
    (P.Sequence(6.0, 6.5, 5000, 10), 1),
    (P.Sequence(1.0, float("inf"), 5000, 10), 1),
    (P.Sequence(1.0, 0.0, 5500, 10), 2),
    (P.Sequence(1.0, 0.0, 5000, 0), 3),
    (P.Sequence(1.0, 0.0, 5000, 10, seed=0x100, order=8), 4),
    (P.Sequence(1.0, 0.0, 5000, 10, order=1), 5),
    (P.Sequence(1.0, 0.0, 5000, 10, order=17), 5),
    (P.Sequence(1.0, 0.0, 5000, 10, hold=0), 6),
]
BAD_SHAPERS = [
    (P.SetShaper(11, (0.1,) * 10, (0,) * 10), 0),
    (P.SetShaper(2, (0.5, 0.4), (0, 3)), 1),  # sum 0.9
    (P.SetShaper(2, (0.5, float("nan")), (0, 3)), 1),
    (P.SetShaper(1, (1.0, 0.25), (0, 0)), 1),  # a tap past n_taps
    (P.SetShaper(2, (2.5, -1.5), (0, 3)), 1),  # |a| > SHAPER_MAX_AMPLITUDE (the Q8.24 FIR)
    (P.SetShaper(2, (0.5, 0.5), (0, P.SHAPER_MAX_DELAY + 1)), 2),  # beyond the ring buffer
    (P.SetShaper(1, (1.0,), (0, 4)), 2),  # a delay past n_taps
    # the firmware checks |a| <= 2 and the zero taps on the IEEE bits: infinities, a tiny tap
    # past n_taps
    (P.SetShaper(2, (float("inf"), -1.0), (0, 3)), 1),
    (P.SetShaper(1, (1.0, float("-inf")), (0, 0)), 1),
    (P.SetShaper(1, (1.0, 1e-38), (0, 0)), 1),
]


def test_sequence_and_shaper_checks_firmware_and_virtual_agree(host_driver):
    """Each bad SEQUENCE / SET_SHAPER gets NACK BAD_VALUE naming the same field on the firmware
    core and on the virtual rig; good ones get ACK; HELLO announces capability bits 12, 13."""
    bad = [m for m, _ in BAD_SEQUENCES + BAD_SHAPERS]
    good = [
        P.SetShaper(2, (2.0, -1.0), (0, 3)),  # |a| = 2 exactly
        P.SetShaper(1, (1.0, -0.0), (0, 0)),  # -0 past n_taps is a zero tap
        P.SetShaper(3, (0.25, 0.5, 0.25), (0, 9, 18)),
        P.SetShaper(0),
    ]
    dev = _host(host_driver)
    dev.send(P.Hello(3))
    for m in bad + good:
        dev.send(m)
    fw, _ = dev.run()
    fw = [m for _, _, m in fw]
    py = _virtual_talk([P.Hello(3)] + bad + good)
    assert [type(m) for m in fw] == [type(m) for m in py]
    for r in (fw, py):
        caps = P.Capability(r[0].capabilities)
        assert P.Capability.SEQUENCE in caps and P.Capability.SHAPER in caps
        assert r[0].protocol_version == P.PROTOCOL_VERSION
        for (m, param), got in zip(BAD_SEQUENCES + BAD_SHAPERS, r[1:]):
            assert isinstance(got, P.Nack), (m, got)
            assert (got.command, got.error, got.param) == (
                int(m.TYPE),
                P.ErrorCode.BAD_VALUE,
                param,
            ), (m, got)
        assert r[-len(good) :] == [P.Ack(P.MsgType.SET_SHAPER)] * len(good)


@pytest.mark.parametrize("loop", [0, 1])
def test_run_refuses_a_gain_the_fixed_point_pid_cannot_hold_firmware_and_virtual_agree(
    host_driver, loop
):
    """RUN: a gain scaled to PWM ticks per count (per count per sample in the velocity loop) must be
    below RUN_GAIN_LIMIT (the firmware's fixed-point PID keeps a 24-bit mantissa): NACK BAD_VALUE
    on both the firmware core and the virtual rig, and a gain at 0.9 of the limit is accepted."""
    Ts = 0.005
    scale = 2 * math.pi / 448 * 1023 / 12.0 / (Ts if loop else 1.0)
    limit = P.RUN_GAIN_LIMIT / scale  # the largest gain in V/rad (V s/rad)
    setup = [P.SetPlant(32.4, 0.025, 12.0, 448), P.SetLimits(2000.0, 300.0, 60.0, 12.0, 0)]
    script = []
    for k, which in ((1.1 * limit, 0), (1.1 * limit, 2), (0.9 * limit, 0)):
        kk = [0.0, 0.0, 0.0]
        kk[which] = f32(k)
        script += [
            P.SetGains(kk[0], kk[1], kk[2], int(Ts * 1e6), loop, 0, 0.0),
            P.Plan(f32(4 * math.pi), 0),  # (the board's own planner, Stojčić eq. 4)
            P.Run(0, 1),
        ]
    dev = _host(host_driver)
    for m in setup + script:
        dev.send(m)
    dev.send(P.Stop())
    fw, _ = dev.run()
    fw = [m for _, _, m in fw]
    py = _virtual_talk(setup + script + [P.Stop()])
    R = int(P.MsgType.RUN)
    for r in (fw, py):
        runs = [m for m in r if getattr(m, "command", None) == R]
        assert [(type(m), getattr(m, "error", None)) for m in runs] == [
            (P.Nack, P.ErrorCode.BAD_VALUE),
            (P.Nack, P.ErrorCode.BAD_VALUE),
            (P.Ack, None),
        ], runs
        assert runs[0].param == runs[1].param == 0xFF


def test_run_refuses_a_shaper_span_the_fixed_point_fir_cannot_hold_firmware_and_virtual_agree(
    host_driver,
):
    """RUN with a shaper: (sum |a| D + 1) max_velocity Ts (counts per rad) must stay below
    SHAPER_SPAN_COUNTS (the ring's Q16.16 windows): with a fine encoder (2^15 counts a
    revolution) a 10 m/s-class velocity limit over a 31-sample shaper at 20 ms is refused NACK
    BAD_VALUE 0xFF on both; the same shaper with a limit below the span is accepted."""
    Ts_us, cpr = 20000, 32768
    shaper = P.SetShaper(2, (0.5, 0.5), (0, 31))
    span = 1.0 * 31 + 1.0
    w_max = P.SHAPER_SPAN_COUNTS / (span * Ts_us * 1e-6 * cpr / (2 * math.pi))  # rad/s
    g = pole_placement_pid(32.4, 0.025, 20).discretize(Ts_us * 1e-6)
    script = [P.SetPlant(32.4, 0.025, 12.0, cpr), shaper]
    for w in (1.05 * w_max, 0.95 * w_max):
        script += [
            P.SetGains(f32(g.kpd), f32(g.kid), f32(g.kdd), Ts_us, 0, 1, 0.0),
            P.SetLimits(2000.0, 300.0, f32(w), 12.0, 0),
            P.Plan(f32(0.5), 0),  # (the board's own planner, Stojčić eq. 4)
            P.Run(0, 1),
            P.Stop(),
        ]
    dev = _host(host_driver)
    for m in script:
        dev.send(m)
    fw, _ = dev.run()
    fw = [m for _, _, m in fw]
    py = _virtual_talk(script)
    R = int(P.MsgType.RUN)
    for r in (fw, py):
        runs = [m for m in r if getattr(m, "command", None) == R]
        assert [(type(m), getattr(m, "param", None)) for m in runs] == [
            (P.Nack, 0xFF),
            (P.Ack, None),
        ], runs


def test_run_move_names_a_gain_the_device_cannot_hold(tmp_path):
    """The client refuses such a gain before anything is sent, naming it and its limit in V/rad."""
    from jerklab.controller import DiscreteGains

    with connect(recordings=tmp_path, progress=False, device=DCMotor()) as rig:
        limit = P.RUN_GAIN_LIMIT / (
            2 * math.pi / rig.counts_per_rev * rig.info.pwm_max / rig.supply_voltage
        )
        prof = plan_sine_jerk(1.0, 2000.0, 300.0, 60.0)
        with pytest.raises(ValueError, match=r"gains\.kdd = .* must be < "):
            rig.run_move(prof, DiscreteGains(10.0, 0.0, 1.01 * limit, 0.005), Ts=0.005, force=True)
        rec = rig.run_move(
            prof, pole_placement_pid(32.4, 0.025, 20).discretize(0.005), Ts=0.005, settle=0.05
        )
        assert rec.metadata["status"] == "complete"


def test_sequence_busy_and_length(host_driver):
    dev = _host(host_driver)
    dev.send(P.Step(1.0, 5000, 50)).send(P.Sequence(1.0, 0.0, 5000, 10)).send(P.SetShaper(0))
    dev.send(P.encode_frame(int(P.MsgType.SEQUENCE), 9, bytes(15)))
    dev.send(P.Stop())
    msgs, _ = dev.run()
    nacks = [m for _, _, m in msgs if isinstance(m, P.Nack)]
    assert [(n.command, n.error) for n in nacks] == [
        (0x0A, P.ErrorCode.BUSY),
        (0x0B, P.ErrorCode.BUSY),
        (0x0A, P.ErrorCode.BAD_LENGTH),
    ]


# ----------------------------------------------------------------------------- the PRBS


@pytest.mark.parametrize(
    "order,seed,hold,amp,off",
    [(8, 1, 1, 3.0, 0.0), (5, 0x13, 3, 2.0, 0.5), (10, 0x2AB, 2, 1.7, -0.3)],
)
def test_prbs_bit_for_bit_firmware_virtual_python(host_driver, order, seed, hold, amp, off):
    """The firmware core's SEQUENCE and the virtual rig's apply exactly jerklab.protocol's PRBS:
    the commanded volts (TELEMETRY reference) equal ``sequence_voltages`` and the PWM is its
    rounding, sample for sample."""
    n = min(300, ((1 << order) - 1) * hold + 7)  # past one period for the short ones
    msg = P.Sequence(amp, off, 5000, n, seed, order, hold)
    dev = _host(host_driver)
    dev.send(msg).wait(50 * (-(-(5 * n + 30) // 50)), heartbeat_every=50)
    fw, pwm_out = dev.run()
    fw_tel = [m for _, _, m in fw if isinstance(m, P.Telemetry)]
    py_tel = [m for m in _virtual_talk([msg], ticks=n + 1) if isinstance(m, P.Telemetry)]
    volts = P.sequence_voltages(msg)
    bits = P.prbs_bits(order, seed, -(-n // hold))
    # lround (half away from zero), as PROTOCOL.md step 4
    expect_pwm = [
        int(np.clip(math.copysign(math.floor(abs(v) * 1023 / 12.0 + 0.5), v), -1023, 1023))
        for v in volts
    ]
    for tel in (fw_tel, py_tel):
        assert [t.index for t in tel] == list(range(n))
        assert [t.reference for t in tel] == volts
        assert [t.pwm for t in tel] == expect_pwm
        assert [int(t.reference > off) for t in tel] == [bits[k // hold] for k in range(n)]
    assert pwm_out[-1][1] == 0  # off at the end


def test_record_prbs_on_the_virtual_rig(tmp_path):
    """``record_prbs`` returns a Recording like ``step``: rest then the PRBS, the applied volts
    in ``control``, the commanded ones in ``reference``; ARX on it recovers the motor."""
    from jerklab.ident import fit_dc_motor

    motor = DCMotor(K=27.5, tau=0.034)
    with connect(recordings=tmp_path, progress=False, device=motor) as rig:
        rec = rig.record_prbs(4.0, order=7, hold=3, rest=0.05)
    n = 127 * 3
    assert rec.metadata["kind"] == "prbs" and rec.metadata["status"] == "complete"
    assert len(rec) == 10 + n and list(rec.index) == list(range(10 + n))
    assert np.all(rec.control[:10] == 0) and np.all(
        np.abs(np.abs(rec.control[10:]) - 4.0) < 12 / 1023
    )
    assert list(rec.reference[10:]) == P.sequence_voltages(P.Sequence(4.0, 0.0, 5000, n, 1, 7, 3))
    assert rec.csv_path is not None and rec.csv_path.exists()
    fit = fit_dc_motor(rec.control, rec.position, rec.Ts, method="pem")
    assert fit.K == pytest.approx(27.5, rel=0.03) and fit.tau == pytest.approx(0.034, rel=0.08)


def test_record_prbs_bad_input_names_the_parameter():
    with connect(progress=False) as rig:
        for kwargs, name in [
            (dict(amplitude=-1), "amplitude"),
            (dict(amplitude=1, order=1), "order"),
            (dict(amplitude=1, seed=0), "seed"),
            (dict(amplitude=1, hold=0), "hold"),
            (dict(amplitude=1, order=4, seed=16), "seed"),
            (dict(amplitude=8, offset=5), "offset"),
            (dict(amplitude=1, order=16, hold=2), "seconds"),
        ]:
            with pytest.raises(ValueError, match=name):
                rig.record_prbs(path=False, **kwargs)


def test_record_prbs_pulled_cable_keeps_every_sample(tmp_path):
    """A cable pulled in the middle of the PRBS: RigConnectionError, and every sample received
    is in the recording on disk with status 'disconnected'."""
    from jerklab.rig.client import Rig
    from jerklab.rig.recording import Recording

    link = VirtualSerial(VirtualDevice(DCMotor()), timeout=0.05, pull_cable_after=2500)
    rig = Rig(link, "virtual", progress=False, recordings=tmp_path, hello_timeout=1.0)
    with pytest.raises(RigConnectionError, match="samples received are saved"):
        rig.record_prbs(3.0, order=8)
    files = sorted(tmp_path.glob("*_prbs.json"))
    assert len(files) == 1
    back = Recording.load(files[0])
    assert back.metadata["status"] == "disconnected"
    assert 50 < len(back) < 10 + 255
    assert list(back.index) == list(range(len(back)))  # nothing lost before the cut


def test_record_prbs_needs_the_capability():
    class OldDevice(VirtualDevice):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.capabilities &= ~(P.Capability.SEQUENCE | P.Capability.SHAPER)

    from jerklab.rig.client import Rig

    rig = Rig(VirtualSerial(OldDevice()), "virtual", progress=False, hello_timeout=1.0)
    with pytest.raises(RigError, match="no SEQUENCE"):
        rig.record_prbs(1.0)
    with pytest.raises(RigError, match="no input shaper"):
        rig.set_shaper([0.5, 0.5])
    rig.close()


# ----------------------------------------------------------------------------- the shaper


def _fir(taps, x):
    """Reference FIR (numpy convolution from rest), independent of the devices' ring buffers."""
    return np.convolve(np.asarray(taps, float), np.asarray(x, float))[: len(x)]


def _zv_taps(f_hz, zeta, Ts):
    """ZV shaper (two impulses, Singer & Seering) on the Ts grid, each impulse split linearly
    between its two neighbouring samples (so the taps sum to 1)."""
    wd = 2 * math.pi * f_hz * math.sqrt(1 - zeta**2)
    K = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    amps, times = [1 / (1 + K), K / (1 + K)], [0.0, math.pi / wd]
    h = np.zeros(int(times[-1] / Ts) + 2)
    for a, t in zip(amps, times):
        i = int(t // Ts)
        fr = t / Ts - i
        h[i] += a * (1 - fr)
        h[i + 1] += a * fr
    return h


def _fixed_fir_bound(taps, r):
    """The fixed-point FIR's bound (counts) against the exact FIR with the same float32 taps:
    the Q8.24 taps' rounding n 2^-25 max|r| plus (2 sum|a| + n + 4) 2^-16 for the Q16.16
    windows' truncation and each product's floor (jerklab.rig.virtual.FixedShaper)."""
    a = np.abs(np.asarray(taps, float))
    n = np.count_nonzero(a)
    return n * 2.0**-25 * np.max(np.abs(r)) + (2 * a.sum() + n + 4) * 2.0**-16


def test_fixed_point_fir_within_its_bound_of_the_exact_fir():
    """The device's fixed-point FIR (FixedShaper, bit for bit the firmware's: test_firmware's
    golden vectors) against numpy's convolution of the reference with the float32 taps, in
    float64: over random shapers (up to 10 taps, delays to 31, amplitudes to +-2) on planned
    moves and random walks within the RUN span check, the shaped position is within
    n 2^-25 max|r| + (2 sum|a| + n + 4) 2^-16 counts of it, its Q16.16 velocity within twice that
    plus 2^-16 of the exact backward difference and its acceleration within four times plus
    2^-15; measured, the error is a fraction of the bound (printed)."""
    from jerklab.rig.virtual import FixedShaper

    rng = np.random.default_rng(7)
    worst = 0.0
    for case in range(30):
        n = int(rng.integers(1, P.SHAPER_MAX_TAPS + 1))
        d = rng.integers(0, P.SHAPER_MAX_DELAY + 1, n)
        a = np.full(n, 9.0)
        while np.abs(a).max() > P.SHAPER_MAX_AMPLITUDE:  # (taps SET_SHAPER takes, summing to 1)
            a = rng.uniform(-1.0, 1.0, n) * (2.0 if case % 3 == 0 else 0.5)
            a[0] += 1.0 - a.sum()
        a = a.astype(np.float32)
        msg = P.SetShaper(n, tuple(float(x) for x in a), tuple(int(x) for x in d))
        shp = FixedShaper(msg)
        vmax = 0.9 * P.SHAPER_SPAN_COUNTS / shp.span  # counts per sample: RUN's check passes
        assert shp.fits(vmax)
        N = 120
        if case % 2:
            dist = float(rng.uniform(0.2, 1.0)) * vmax * 60
            prof = plan_sine_jerk(dist, 1e9, vmax**2 / dist * 8, vmax)  # (time unit: samples)
            r = prof.sample(np.arange(N) - float(rng.integers(0, 20))).position
        else:  # (drifting: far from 0 by the end)
            r = np.cumsum(np.clip(rng.normal(vmax / 2, vmax / 3, N), -vmax, vmax))
        R = np.array([int(round(x * 2.0**32)) for x in r], dtype=object)
        Rs, v, acc = shp.run(R)
        rin = np.array([float(x) for x in R]) / 2.0**32
        taps = np.zeros(P.SHAPER_MAX_DELAY + 1)
        np.add.at(taps, d, a.astype(float))
        exact = np.convolve(taps, rin)[:N]
        B = _fixed_fir_bound(a, rin)
        err = np.abs(np.array([float(x) for x in Rs]) / 2.0**32 - exact)
        assert err.max() <= B, (case, err.max(), B)
        ev = np.diff(np.r_[0.0, exact])
        assert np.max(np.abs(np.array(v) / 65536.0 - ev)) <= 2 * B + 2.0**-16, case
        ea = np.diff(np.r_[0.0, ev])
        assert np.max(np.abs(np.array(acc) / 65536.0 - ea)) <= 4 * B + 2.0**-15, case
        worst = max(worst, err.max() / B)
    print(f"fixed-point FIR: worst error {worst:.2f} of its bound")
    assert worst > 0.01  # (the comparison sees the quantisation, it is not vacuous)


def test_shaped_run_firmware_virtual_and_numpy_agree(host_driver):
    """A shaped closed-loop run: the firmware core's TELEMETRY reference, the virtual rig's and
    the numpy convolution of the planned profile agree sample by sample (within 2e-6 of the
    distance: the fixed-point FIR on the float32 profile), the run lasts the shaper's last
    delay longer, and both devices end at the distance."""
    Ts = 0.005
    taps = _zv_taps(7.0, 0.05, Ts)
    delays = np.flatnonzero(taps)
    shaper = P.SetShaper(
        len(delays), tuple(f32(a) for a in taps[delays]), tuple(int(d) for d in delays)
    )
    distance = f32(4 * math.pi)
    g = pole_placement_pid(32.4, 0.025, 20).discretize(Ts)
    setup = [
        P.SetPlant(32.4, 0.025, 12.0, 448),
        P.SetGains(f32(g.kpd), f32(g.kid), f32(g.kdd), 5000, 0, 1, 0.0),
        P.SetLimits(2e4, 300.0, 100.0, 12.0, 0),
        shaper,
        P.Plan(distance, 0),
        P.Run(30, 1),
    ]
    prof = plan_sine_jerk(distance, 2e4, 300.0, 100.0)
    n = math.ceil(prof.duration / Ts - 1e-4) + 1
    D = int(delays[-1])
    dev = _host(host_driver)
    for m in setup:
        dev.send(m)
    dev.wait((n + D + 30 + 2) * 5)
    fw, _ = dev.run()
    fw_tel = [m for _, _, m in fw if isinstance(m, P.Telemetry)]
    py_tel = [m for m in _virtual_talk(setup, ticks=n + D + 31) if isinstance(m, P.Telemetry)]
    k = np.arange(n + D + 30)
    expect = _fir(taps, prof.sample(k * Ts).position)
    for tel in (fw_tel, py_tel):
        assert len(tel) == n + D + 30
        ref = np.array([t.reference for t in tel])
        assert np.max(np.abs(ref - expect)) <= 2e-6 * distance
        settling = np.array([bool(t.flags & P.TELEMETRY_SETTLING) for t in tel])
        assert not settling[: n + D].any() and settling[n + D :].all()
        assert abs(tel[-1].counts - distance * 448 / (2 * math.pi)) <= 2
    fr = np.array([t.reference for t in fw_tel])
    pr_ = np.array([t.reference for t in py_tel])
    assert np.max(np.abs(fr - pr_)) <= 2e-6 * distance
    # the same loop on the same motor: counts within one (an encoder edge float32 and float64
    # put on either side of a sample), and the PWM equal (within float32 rounding) except in
    # the sample of a count difference and the two after it (the PID's difference terms)
    dc = np.abs(np.array([t.counts for t in fw_tel]) - np.array([t.counts for t in py_tel]))
    dp = np.abs(np.array([t.pwm for t in fw_tel]) - np.array([t.pwm for t in py_tel]))
    assert dc.max() <= 1 and np.mean(dc == 0) > 0.9
    near = np.convolve(dc != 0, np.ones(3), mode="full")[: len(dc)] > 0
    assert dp[~near].max() <= 2


def test_set_shaper_client_and_ts_guard():
    with connect(progress=False) as rig:
        msg = rig.set_shaper(_zv_taps(8.0, 0.02, 0.005))
        assert msg.n_taps == 3 and abs(sum(msg.amplitudes) - 1) < 1e-6
        with pytest.raises(ValueError, match="sum to 1"):
            rig.set_shaper([0.5, 0.4])
        with pytest.raises(ValueError, match=f"at most {P.SHAPER_MAX_DELAY} samples"):
            rig.set_shaper(np.r_[0.5, np.zeros(200), 0.5])
        with pytest.raises(ValueError, match="at most 10"):
            rig.set_shaper(np.full(11, 1 / 11))
        prof = plan_sine_jerk(2.0, 2e4, 300.0, 100.0)
        g = pole_placement_pid(32.4, 0.025, 20)
        with pytest.raises(ValueError, match="shaper was set for Ts"):
            rig.run_move(prof, g, Ts=0.004, path=False)
        rec = rig.run_move(prof, g, path=False, settle=0.05)
        assert rec.metadata["shaper"]["delays"] == list(msg.delays[:3])
        rig.set_shaper(None)
        plain = rig.run_move(prof, g, path=False, settle=0.05)
        assert "shaper" not in plain.metadata and len(plain) == len(rec) - msg.delays[2]


class _ShaperLike:
    """Duck-typed shaper: what ``jerklab.shaping.input_shaper`` returns needs only ``.fir(Ts)``."""

    def __init__(self, f, z):
        self.f, self.z = f, z

    def fir(self, Ts):
        return _zv_taps(self.f, self.z, Ts)


def _residual_deflection(rig, shaper, f_mode, zeta):
    """Run one move on a virtual flexible rig; the largest shaft deflection |θ_l − θ_m| after
    the shaped move has ended (rad), from the model's state each tick."""
    dev = rig.link.device
    log = []
    tick = dev.tick

    def logged():
        tick()
        log.append(dev.x[2] - dev.x[0])

    dev.tick = logged
    try:
        rig.set_shaper(shaper)
        prof = plan_sine_jerk(4 * math.pi, 2e4, 300.0, 100.0)
        g = discrete_pole_placement_pid(32.4, 0.025, 25.0, 1.0, Ts=0.005)
        rec = rig.run_move(prof, g, path=False, settle=0.6)
    finally:
        dev.tick = tick
    end = int(np.argmax(rec.flags & P.TELEMETRY_SETTLING))
    return float(np.max(np.abs(log[end : len(rec)])))


def test_zv_shaper_stops_the_ringing_on_the_virtual_flexible_rig():
    """On the flexible load, a ZV shaper tuned to the mode leaves a small fraction of the
    unshaped residual deflection; a shaper 40 % off the mode leaves much more (a ZV shaper's
    narrow insensitivity)."""
    with connect(device=FlexibleDCMotor(), progress=False) as rig:
        assert isinstance(rig.link.device.motor, FlexibleDCMotor)
        from jerklab.lab.motors import coupled_mode

        f, z = coupled_mode(rig.link.device.motor)
        none = _residual_deflection(rig, None, f, z)
        tuned = _residual_deflection(rig, _ShaperLike(f, z), f, z)
        off = _residual_deflection(rig, _ShaperLike(1.4 * f, z), f, z)
    assert none > 0.05  # the load rings after the move
    assert tuned < 0.1 * none
    assert off > 3 * tuned


# ----------------------------------------------------------------------------- flexible students


def test_student_flexible_motor_is_hidden_seeded_and_in_range(monkeypatch):
    from jerklab import lab
    from jerklab.lab.motors import MODE_RANGES, student_motor
    from jerklab.lab.motors import hidden_truth as _truth

    monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", "k1")
    a = student_motor("alice", plant="flexible")
    a2 = student_motor("Alice ", plant="flexible")
    b = student_motor("bob", plant="flexible")
    rigid = student_motor("alice")
    assert (a.mode_frequency, a.mode_damping) == (a2.mode_frequency, a2.mode_damping)
    assert a.mode_frequency != b.mode_frequency
    assert (a.K, a.tau, a.encoder_ppr) == (rigid.K, rigid.tau, rigid.encoder_ppr)  # same motor
    lo, hi = MODE_RANGES["mode_hz"]
    for m in (a, b):
        assert 2 * math.pi * lo <= m.mode_frequency <= 2 * math.pi * hi
        assert MODE_RANGES["mode_damping"][0] <= m.mode_damping <= MODE_RANGES["mode_damping"][1]
    t = _truth(a)
    assert 0.8 * lo < t["mode_hz"] < 1.5 * hi and 0 < t["mode_zeta"] < 0.3
    monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", "k2")
    assert student_motor("alice", plant="flexible").mode_frequency != a.mode_frequency
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", "k1")
        rig = lab.connect_student("alice", plant="flexible", progress=False)
        hidden = student_motor("alice", plant="flexible")
    try:
        truth = _truth(hidden)
        text = repr(rig) + repr(rig.link.device) + repr(hidden) + str(rig.device_info())
        rec = rig.step(3.0, 0.3, path=False)
        text += repr(rec) + str(rec.metadata)
        for v in (
            truth["K"],
            truth["tau"],
            truth["mode_hz"],
            truth["mode_zeta"],
            hidden.mode_frequency,
            hidden.mode_damping,
        ):
            for shown in (f"{v:.5g}", f"{v:.6g}", repr(v)):
                assert shown not in text, v
        assert isinstance(rig.link.device.motor, FlexibleDCMotor)
    finally:
        rig.close()


def test_connect_takes_the_flexible_load_as_a_device():
    """The flexible load is a device (a FlexibleDCMotor), for simulated rigs only; the old
    plant= keyword names its replacement."""
    with pytest.raises(TypeError, match=r"device=FlexibleDCMotor\(\)"):
        connect(plant="flexible")
    with pytest.raises(ValueError, match="device.motor applies to a simulated rig"):
        connect("/dev/ttyACM9", device=FlexibleDCMotor())
    with pytest.raises(TypeError, match="device must be a jerklab.rig.Device"):
        connect(device="flexible")


def test_random_sequence_and_shaper_commands_reply_alike_on_firmware_and_virtual(host_driver):
    """400 random SEQUENCE and SET_SHAPER commands, most near a limit (amplitude + |offset| at the
    voltage clamp, taps summing to 1 ± the tolerance, delays at the ring's end, seeds with zero
    low bits, NaN and inf): the firmware core and the virtual rig answer each the same way
    (ACK, or NACK with the same error and field). Sequences are stopped at once."""
    rng = np.random.default_rng(2026)
    f = lambda x: float(np.float32(x))  # noqa: E731
    msgs = []
    for i in range(200):
        amp = f(rng.choice([rng.uniform(0, 12), 6.0, -0.0, -1e-3, float("nan"), float("inf")]))
        off = f(
            rng.choice(
                [rng.uniform(-12, 12), 12.0 - amp if amp == amp and amp < 1e30 else 0.0, -6.0]
            )
        )
        order = int(rng.choice([rng.integers(0, 20), 2, 16, 17]))
        seed = int(rng.choice([rng.integers(0, 65536), 1 << min(order, 15), 0]))
        msgs.append(
            P.Sequence(
                amp,
                off,
                int(rng.choice([5000, 1000, 0, 1500, 65000, 65535])),
                int(rng.choice([0, 1, 10])),
                seed,
                order,
                int(rng.choice([0, 1, 3])),
            )
        )
    for i in range(200):
        n = int(rng.choice([0, 1, 3, 10, 11, int(rng.integers(0, 12))]))
        k = min(n, 10)
        a = rng.dirichlet(np.ones(k)) if k else np.zeros(0)
        a = [f(x) for x in a]
        if k and rng.random() < 0.4:
            a[0] = f(a[0] + rng.choice([9e-4, 1.1e-3, -2e-3, 0.5]))
        if k and rng.random() < 0.05:
            a[-1] = float("nan")
        d = [int(rng.choice([rng.integers(0, 128), 127, 128, 255])) for _ in range(k)]
        extra_a = [f(rng.choice([0.0, 0.0, 0.25]))] if k < 10 and rng.random() < 0.2 else []
        extra_d = (
            [int(rng.choice([0, 0, 5]))] if k + len(extra_a) < 10 and rng.random() < 0.2 else []
        )
        msgs.append(P.SetShaper(n, tuple(a + extra_a), tuple(d + extra_d)))
    dev = _host(host_driver)
    py_dev = VirtualDevice(DCMotor(), clock=lambda: 0.0)
    py = []
    for m in msgs:
        dev.send(m)
        if isinstance(m, P.Sequence):
            dev.send(P.Stop())
        py_dev.receive(P.encode(m, 1))
        if isinstance(m, P.Sequence):
            py_dev.receive(P.encode(P.Stop(), 2))
        py += [
            x
            for x in (P.parse(fr) for fr in P.Decoder().feed(py_dev.read_output()))
            if isinstance(x, (P.Ack, P.Nack)) and x.command != P.MsgType.STOP
        ]
    fw, _ = dev.run()
    fw = [x for _, _, x in fw if isinstance(x, (P.Ack, P.Nack)) and x.command != P.MsgType.STOP]
    assert len(fw) == len(py) == len(msgs)
    for m, a_, b_ in zip(msgs, fw, py):
        assert a_ == b_, (m, a_, b_)
    kinds = {(type(x).__name__, getattr(x, "param", None)) for x in fw}
    assert len(kinds) >= 8  # acks and NACKs naming many different fields
