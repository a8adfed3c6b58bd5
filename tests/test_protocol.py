"""Protocol round-trips, CRC check values, the golden frames of firmware/PROTOCOL.md."""

from __future__ import annotations

import binascii
import dataclasses
import math
import os
import re
import struct

import pytest

from jerklab import protocol as P

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE the textbook way (bit by bit), independent of the table."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc_check_value():
    # the catalogue check value of CRC-16/CCITT-FALSE
    assert P.crc16_ccitt_false(b"123456789") == 0x29B1
    assert _crc_bitwise(b"123456789") == 0x29B1
    assert binascii.crc_hqx(b"123456789", 0xFFFF) == 0x29B1


def test_crc_table_matches_bitwise():
    import random

    rng = random.Random(1)
    for _ in range(200):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(70)))
        assert P.crc16_ccitt_false(data) == _crc_bitwise(data)


EXAMPLES = [
    P.Hello(),
    P.SetPlant(K=32.4, tau=0.025, supply_voltage=12.0, counts_per_rev=448),
    P.SetGains(
        kpd=1.0, kid=0.1, kdd=2.0, Ts_us=5000, loop=P.LoopType.VELOCITY, flags=0, gamma=0.25
    ),
    P.SetLimits(
        max_jerk=2e4,
        max_accel=300.0,
        max_velocity=100.0,
        max_voltage=12.0,
        host_timeout_ms=500,
        max_error=0.25,
        runaway_ms=150,
        saturation_ms=300,
    ),
    P.Plan(distance=-31.4159, planner=P.Planner.SINE_JERK),
    P.Run(settle_samples=40, decimation=2),
    P.Stop(),
    P.Step(voltage=-6.0, Ts_us=5000, n_samples=200),
    P.Heartbeat(),
    P.Sequence(
        amplitude=2.5, offset=-0.5, Ts_us=2000, n_samples=1023, seed=0x1234, order=10, hold=3
    ),
    P.SetShaper(n_taps=4, amplitudes=(0.125, 0.375, 0.375, 0.125), delays=(0, 7, 14, 21)),
    P.Retarget(43, 0.2125, 1, 5, 25.0, 0.1, 0.05, 1),
    P.Ack(command=P.MsgType.SET_GAINS),
    P.Nack(command=P.MsgType.SET_LIMITS, error=P.ErrorCode.BAD_VALUE, param=3),
    P.HelloReply(1, 0, 1, 2, 0x1F1, 1000, 1023, "jerklab-uno"),
    P.PlanInfo(0.1, 0.2, 0.4, 81),
    P.Telemetry(index=2**32 - 1, reference=-1.5, counts=-(2**31), pwm=-1023, flags=3),
    P.EndOfRun(reason=P.EndReason.HOST_TIMEOUT, samples=81, rx_errors=3, overruns=1),
    P.EndOfRun(reason=P.EndReason.RUNAWAY, samples=12, rx_errors=0, overruns=0, detail=-35.0),
    P.DeviceError(code=3, detail=65535),
    P.HostLoop(Ts_us=10000, n_samples=201, max_misses=3),
    P.HostVoltage(index=2**32 - 1, voltage=-11.5, reference=3.25, flags=1),
    P.HostSample(index=7, counts=-(2**31), pwm=-1023, misses=65535, miss_run=255, flags=5),
    P.PlanSegment(
        index=3,
        kind=P.SegmentKind.HALF_SINE,
        duration=0.0125,
        x0=1.5,
        v0=-3.25,
        a0=120.0,
        jerk=-2e4,
    ),
    P.PlanCommit(
        n_segments=7,
        target=-31.4159,
        accel_time=0.1,
        cruise_time=0.2,
        cruise_velocity=60.0,
        planner=P.PLANNER_NONE,
    ),
]


def _f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(msg):
    for seq in (0, 1, 255):
        wire = P.encode(msg, seq)
        assert wire[:2] == P.SYNC
        assert wire[2] == len(wire) - 5
        frames = P.Decoder().feed(wire)
        assert len(frames) == 1
        assert frames[0].seq == seq and frames[0].type == msg.TYPE
        back = P.parse(frames[0])
        for f in dataclasses.fields(msg):
            a, b = getattr(msg, f.name), getattr(back, f.name)
            if isinstance(a, float):
                assert b == _f32(a)  # float32 on the wire
            else:
                assert a == b


def test_every_type_has_an_example_and_fits():
    assert {type(m) for m in EXAMPLES} == set(P.MESSAGES.values())
    for cls in P.MESSAGES.values():
        assert struct.calcsize(cls.FORMAT) <= P.MAX_PAYLOAD
    # the Uno's 64-byte UART receive buffer holds one maximal frame of the types it receives
    # (SET_SHAPER, 58 bytes, the largest since version 3); the others stay within 33 bytes
    assert max(struct.calcsize(c.FORMAT) for c in P.MESSAGES.values()) + P.MIN_FRAME <= 64
    assert (
        max(struct.calcsize(c.FORMAT) for c in P.MESSAGES.values() if c is not P.SetShaper)
        + P.MIN_FRAME
        <= 34
    )


def test_protocol_version_is_stated_once():
    """PROTOCOL.md's title, protocol.py and the firmware core name the same version."""
    text = open(os.path.join(ROOT, "firmware", "PROTOCOL.md"), encoding="utf-8").read()
    assert re.search(r"^# jerklab rig protocol, version (\d+)$", text, re.M).group(1) == str(
        P.PROTOCOL_VERSION
    )
    hdr = open(
        os.path.join(ROOT, "firmware", "jerklab_rig", "src", "jl_protocol.h"), encoding="utf-8"
    ).read()
    assert re.search(r"kProtocolVersion = (\d+);", hdr).group(1) == str(P.PROTOCOL_VERSION)
    assert re.search(r"kMaxPlanSamples = (\d+)UL;", hdr).group(1) == str(P.MAX_PLAN_SAMPLES)


def test_golden_frames_match_protocol_md():
    """Every golden frame in firmware/PROTOCOL.md is what protocol.py sends."""
    text = open(os.path.join(ROOT, "firmware", "PROTOCOL.md"), encoding="utf-8").read()
    golden = text.split("## Golden frames", 1)[1]
    hexes = [bytes.fromhex(h) for h in re.findall(r"((?:[0-9a-f]{2} ){4,}[0-9a-f]{2})", golden)]
    expected = [
        P.Hello(2),
        P.SetPlant(32.4, 0.025, 12.0, 448),
        P.SetGains(1.0, 0.1, 2.0, 5000, 0, 1, 0.0),
        P.SetLimits(2e4, 300, 100, 12, 1000, 0.5, 200, 500),
        P.Plan(31.4159, 0),
        P.Run(40, 1),
        P.Stop(),
        P.Step(6.0, 5000, 200),
        P.Heartbeat(),
        P.Sequence(2.0, 0.5, 5000, 255, 1, 8, 1),
        P.SetShaper(3, (0.25, 0.5, 0.25), (0, 9, 18)),
        P.Ack(2),
        P.Nack(3, 3, 1),
        P.Nack(5, 8, 0),
        P.HelloReply(2, 0, 1, 0, 0x1F1, 1000, 1023, "jerklab-uno"),
        P.PlanInfo(0.1, 0.2, 0.4, 81),
        P.Telemetry(12, 1.5, -300, -1023, 1),
        P.EndOfRun(0, 81, 0, 0, 0.0),
        P.EndOfRun(4, 169, 0, 0, 0.52),
        P.DeviceError(3, 1),
        P.Retarget(43, 0.2125, 1, 5, 25.0, 0.1, 0.05, 1),
        P.HostLoop(10000, 200, 3),
        P.HostVoltage(7, 2.5, 0.75, 1),
        P.HostSample(8, -300, 512, 2, 1, 1),
        P.EndOfRun(8, 9, 0, 0, 4.0),
        P.PlanSegment(2, 1, 0.0125, 1.5, -3.25, 120.0, -2e4),
        P.PlanCommit(5, 3.0, 0.1, 0.2, 25.0, 2),
    ]
    assert len(hexes) == len(expected)
    for h, m in zip(hexes, expected):
        assert P.encode(m, 5) == h, type(m).__name__
        assert _crc_bitwise(h[2:-2]) == h[-2] | (h[-1] << 8)


def test_documented_payload_sizes():
    text = open(os.path.join(ROOT, "firmware", "PROTOCOL.md"), encoding="utf-8").read()
    sizes = dict(
        re.findall(r"([A-Z_]+) (\d+)[,.]", text.split("Payload sizes:", 1)[1].split("largest")[0])
    )
    for cls in P.MESSAGES.values():
        assert int(sizes[cls.TYPE.name]) == struct.calcsize(cls.FORMAT), cls.TYPE.name


def test_bad_payload_lengths_and_types():
    with pytest.raises(P.ProtocolError, match="Telemetry payload must be 15 bytes"):
        P.Telemetry.unpack(b"\x00" * 14)
    with pytest.raises(P.ProtocolError, match="unknown message type 0x42"):
        P.parse(P.Frame(0x42, 0, b""))
    with pytest.raises(P.ProtocolError, match="payload must be <= 64"):
        P.encode_frame(0x01, 0, bytes(65))
    with pytest.raises(P.ProtocolError, match="seq"):
        P.encode_frame(0x01, 256, b"")
    with pytest.raises(P.ProtocolError, match="cannot pack"):
        P.encode(P.Step(voltage=1.0, Ts_us=70000, n_samples=1))


def test_field_names_for_nack():
    assert P.payload_field_name(P.MsgType.SET_LIMITS, 3) == "max_voltage"
    assert P.payload_field_name(P.MsgType.SET_GAINS, 3) == "Ts_us"
    assert "unknown type" in P.payload_field_name(0x42, 0)


def test_decoder_any_chunking():
    wire = b"".join(P.encode(m, i) for i, m in enumerate(EXAMPLES))
    for chunk in (1, 2, 3, 7, 64, len(wire)):
        d = P.Decoder()
        got = []
        for i in range(0, len(wire), chunk):
            got += d.feed(wire[i : i + chunk])
        assert [f.seq for f in got] == list(range(len(EXAMPLES)))
        assert d.stats.dropped == 0 and d.stats.skipped_bytes == 0 and d.pending == 0


def test_decoder_resyncs_inside_a_truncated_frame():
    good = P.encode(P.Telemetry(1, 0.5, 10, 20, 0), 1)
    nxt = P.encode(P.Telemetry(2, 0.5, 11, 21, 0), 2)
    d = P.Decoder()
    frames = d.feed(good[:-6] + nxt)  # first frame cut short, the next starts inside it
    assert [f.seq for f in frames] == [2]
    assert d.stats.bad_crc == 1 and d.stats.frames == 1


def test_decoder_bad_length_and_flush():
    d = P.Decoder()
    assert d.feed(b"\xa5\x5a\x00\xa5\x5a\xff") == []
    assert d.stats.bad_length == 2
    frame = P.encode(P.Ack(1), 9)
    assert d.feed(frame[:5]) == [] and d.pending == 5
    assert d.flush() == []
    assert d.stats.truncated == 1 and d.pending == 0
    assert [f.seq for f in d.feed(frame)] == [9]


def test_float_nan_travels_but_is_visible():
    # the wire can carry NaN (the device then NACKs BAD_VALUE); the host never sends one
    m = P.parse(P.Decoder().feed(P.encode(P.Plan(math.nan, 0)))[0])
    assert math.isnan(m.distance)


# ----------------------------------------------------------------------------- version 3


def test_prbs_masks_are_maximal_length():
    """Every order's LFSR visits all 2**n - 1 nonzero states (checked by brute force), and a
    period holds 2**(n-1) ones and 2**(n-1) - 1 zeros (the balance of an m-sequence)."""
    for order, mask in P.PRBS_TAPS.items():
        state, seen = 1, set()
        while state not in seen:
            seen.add(state)
            b = state & 1
            state >>= 1
            if b:
                state ^= mask
        assert len(seen) == 2**order - 1 and state == 1, order
        bits = P.prbs_bits(order, 1, 2**order - 1)
        assert sum(bits) == 2 ** (order - 1), order
        assert P.prbs_bits(order, 1, 2 ** (order + 1) - 2)[2**order - 1 :] == bits  # periodic


def test_prbs_autocorrelation_is_two_valued():
    """The ±1 m-sequence's periodic autocorrelation is N at lag 0 and -1 at every other lag
    (independent of how the bits were produced: a property of maximal-length sequences)."""
    import numpy as np

    for order in (5, 8, 11):
        n = 2**order - 1
        x = 2 * np.array(P.prbs_bits(order, 7, n)) - 1
        r = np.array([np.dot(x, np.roll(x, k)) for k in range(n)])
        assert r[0] == n and np.all(r[1:] == -1)


def test_prbs_bits_bad_input():
    with pytest.raises(ValueError, match="order"):
        P.prbs_bits(17, 1, 5)
    with pytest.raises(ValueError, match="seed"):
        P.prbs_bits(4, 0x10, 5)  # low 4 bits zero
    with pytest.raises(TypeError, match="seed"):
        P.prbs_bits(4, 1.5, 5)


def test_sequence_voltages_hold_and_levels():
    m = P.Sequence(2.0, 0.5, 5000, 10, seed=1, order=3, hold=3)
    v = P.sequence_voltages(m)
    bits = P.prbs_bits(3, 1, 4)
    assert v == [2.5 if bits[k // 3] else -1.5 for k in range(10)]


def test_set_shaper_pads_and_refuses_too_many_taps():
    m = P.SetShaper(2, (0.5, 0.5), (0, 10))
    assert m.amplitudes == (0.5, 0.5) + (0,) * 8 and len(m.delays) == 10
    assert len(m.pack()) == 51
    with pytest.raises(P.ProtocolError, match="amplitudes has 11 entries"):
        P.SetShaper(11, (0.1,) * 11, (0,) * 11)
    with pytest.raises(P.ProtocolError, match=r"delays\[1\]"):
        P.SetShaper(2, (0.5, 0.5), (0, 300)).pack()
    assert P.payload_field_name(P.MsgType.SET_SHAPER, 2) == "delays"
    assert P.payload_field_name(P.MsgType.SEQUENCE, 5) == "order"


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_f32s = st.floats(width=32, allow_nan=False)


@settings(deadline=None)
@given(
    amp=_f32s,
    off=_f32s,
    ts=st.integers(0, 0xFFFF),
    n=st.integers(0, 0xFFFF),
    seed=st.integers(0, 0xFFFF),
    order=st.integers(0, 255),
    hold=st.integers(0, 255),
    seq=st.integers(0, 255),
)
def test_sequence_encoding_property(amp, off, ts, n, seed, order, hold, seq):
    """Any in-range Sequence survives encode -> decode exactly, in 16 payload bytes laid out
    as PROTOCOL.md says (independent struct layout below)."""
    m = P.Sequence(amp, off, ts, n, seed, order, hold)
    wire = P.encode(m, seq)
    assert len(wire) == 16 + P.MIN_FRAME
    assert wire[5:-2] == struct.pack("<ffHHHBB", amp, off, ts, n, seed, order, hold)
    (f,) = P.Decoder().feed(wire)
    assert (f.type, f.seq) == (0x0A, seq) and P.parse(f) == m


@settings(deadline=None)
@given(
    taps=st.lists(st.tuples(_f32s, st.integers(0, 255)), max_size=10),
    n=st.integers(0, 255),
    seq=st.integers(0, 255),
)
def test_set_shaper_encoding_property(taps, n, seq):
    """Any SetShaper of at most 10 (amplitude, delay) pairs round-trips; the payload is
    n, the 10 amplitudes then the 10 delays, zero-padded."""
    amps = tuple(a for a, _ in taps)
    dels = tuple(d for _, d in taps)
    m = P.SetShaper(n, amps, dels)
    payload = m.pack()
    pad = 10 - len(taps)
    assert payload == struct.pack("<B", n) + struct.pack("<10f", *(amps + (0.0,) * pad)) + bytes(
        dels + (0,) * pad
    )
    (f,) = P.Decoder().feed(P.encode(m, seq))
    back = P.parse(f)
    assert back == m and back.n_taps == n and f.seq == seq
