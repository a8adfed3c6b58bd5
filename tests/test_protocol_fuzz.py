"""Property-based fuzzing of the streaming decoder: random, corrupted, truncated frames.

The property: the decoder never raises, every frame it returns passed the CRC,
and every frame that reached it intact is returned at its own stream offset —
unless a corrupted candidate happened to pass the 16-bit CRC by chance (about
1 in 65536) and covers it; those are accounted for exactly by offset.

Volume: ``test_fuzz_streams`` runs 2000 examples of 60 frames (1.2e5 frames,
about a third corrupted), and ``test_bulk_1e5_frames`` decodes 1e5 seeded
frames in one stream, so the 1e5 figure holds in every hypothesis profile.
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jerklab import protocol as P


def _random_frame(rng: random.Random) -> bytes:
    n = rng.choice((0, 1, 3, 5, 8, 14, 15, 16, 26, 64, rng.randrange(65)))
    return P.encode_frame(rng.randrange(256), rng.randrange(256), rng.randbytes(n))


def _corrupt(frame: bytes, rng: random.Random, kind: int) -> bytes:
    b = bytearray(frame)
    if kind == 0:  # flip 1..4 bits anywhere (sync included)
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == 1:  # truncated (pulled cable, lost bytes)
        b = b[: rng.randrange(1, len(b))]
    elif kind == 2:  # a byte dropped in the middle
        del b[rng.randrange(len(b))]
    elif kind == 3:  # a byte inserted
        b.insert(rng.randrange(len(b) + 1), rng.randrange(256))
    elif kind == 4:  # length byte replaced
        b[2] = rng.randrange(256)
    return bytes(b)


def _build_stream(rng: random.Random, n_frames: int, p_corrupt: float, p_garbage: float):
    """Return (stream bytes, [(offset, frame bytes) of intact frames])."""
    parts, intact, off = [], [], 0
    for _ in range(n_frames):
        if rng.random() < p_garbage:
            g = rng.randbytes(rng.randrange(1, 40))
            if rng.random() < 0.3:
                g += P.SYNC  # a dangling sync pair
            parts.append(g)
            off += len(g)
        f = _random_frame(rng)
        if rng.random() < p_corrupt:
            f2 = _corrupt(f, rng, rng.randrange(5))
            if f in f2:  # e.g. a byte inserted before or after it
                intact.append((off + f2.index(f), f))
            f = f2
        else:
            intact.append((off, f))
        parts.append(f)
        off += len(f)
    return b"".join(parts), intact


def _decode_chunked(stream: bytes, rng: random.Random, max_chunk: int):
    d = P.Decoder()
    out, i = [], 0
    while i < len(stream):
        n = rng.randint(1, max_chunk)
        out += d.feed(stream[i : i + n])
        i += n
    out += d.flush()
    return d, out


def _check(stream: bytes, intact, decoder: P.Decoder, frames) -> int:
    """Assert the property; return the number of chance CRC passes (spurious frames)."""
    got = {f.offset: f for f in frames}
    assert len(got) == len(frames)
    offsets = sorted(got)
    assert [f.offset for f in frames] == offsets  # in stream order
    for f in frames:  # each really is a good frame there
        wire = P.encode_frame(f.type, f.seq, f.payload)
        assert stream[f.offset : f.offset + len(wire)] == wire
    intact_offsets = {o for o, _ in intact}
    spurious = [f for f in frames if f.offset not in intact_offsets]
    covered = [(f.offset, f.offset + f.size) for f in spurious]
    for o, wire in intact:
        if o in got:
            assert got[o].type == wire[3] and got[o].seq == wire[4] and got[o].size == len(wire)
        else:  # only a chance CRC pass may hide it
            assert any(a < o + len(wire) and o < b for a, b in covered), f"lost intact frame at {o}"
    assert decoder.stats.frames == len(frames)
    assert decoder.pending == 0
    return len(spurious)


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    p_corrupt=st.sampled_from([0.0, 0.1, 0.35, 0.7, 1.0]),
    p_garbage=st.sampled_from([0.0, 0.05, 0.3]),
    max_chunk=st.sampled_from([1, 5, 23, 64, 4096]),
)
def test_fuzz_streams(seed, p_corrupt, p_garbage, max_chunk):
    rng = random.Random(seed)
    stream, intact = _build_stream(rng, 60, p_corrupt, p_garbage)
    decoder, frames = _decode_chunked(stream, rng, max_chunk)
    _check(stream, intact, decoder, frames)


@settings(deadline=None)
@given(
    st.lists(
        st.one_of(
            st.tuples(
                st.just("frame"), st.integers(0, 255), st.integers(0, 255), st.binary(max_size=64)
            ),
            st.tuples(st.just("junk"), st.binary(max_size=80)),
            st.tuples(
                st.just("cut"), st.integers(0, 255), st.binary(max_size=64), st.integers(1, 70)
            ),
        ),
        max_size=30,
    ),
    st.integers(1, 80),
)
def test_fuzz_structured(items, chunk):
    """Hypothesis builds the stream itself (shrinks to a minimal failing stream)."""
    parts, intact, off = [], [], 0
    for it in items:
        if it[0] == "frame":
            w = P.encode_frame(it[1], it[2], it[3])
            intact.append((off, w))
        elif it[0] == "junk":
            w = it[1]
        else:
            full = P.encode_frame(it[1], 0, it[2])
            w = full[: min(it[3], len(full) - 1)]
        parts.append(w)
        off += len(w)
    stream = b"".join(parts)
    d = P.Decoder()
    frames = []
    for i in range(0, len(stream), chunk):
        frames += d.feed(stream[i : i + chunk])
    frames += d.flush()
    _check(stream, intact, d, frames)


@settings(deadline=None)
@given(st.binary(max_size=2000))
def test_pure_noise_never_crashes(data):
    d = P.Decoder()
    frames = d.feed(data) + d.flush()
    for f in frames:  # anything returned passed the CRC
        w = P.encode_frame(f.type, f.seq, f.payload)
        assert data[f.offset : f.offset + len(w)] == w
    assert d.pending == 0


def test_bulk_1e5_frames():
    """1e5 frames, 30 % corrupted, random chunking: count what is lost and why."""
    rng = random.Random(20261122)
    stream, intact = _build_stream(rng, 100_000, 0.3, 0.05)
    decoder, frames = _decode_chunked(stream, rng, 256)
    spurious = _check(stream, intact, decoder, frames)
    got = {f.offset for f in frames}
    recovered = sum(1 for o, _ in intact if o in got)
    assert len(intact) > 65_000
    # a chance CRC pass costs at most a few intact frames; expect ~1 per 65536 candidates
    assert spurious <= 10
    assert recovered >= len(intact) - 12 * spurious
    assert decoder.stats.dropped > 25_000
