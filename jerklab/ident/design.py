"""Input design for identification: the sample-time rule of Stojčić §4A (ASCII:
Stojcic), steps and PRBS."""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from jerklab._validate import as_int, as_nonnegative, as_positive, as_real


def sample_time_range(tau):
    """Stojčić §4A rule Ts = tau/(2...5): returns (tau/5, tau/2), in s. tau = 25 ms -> 5...12.5 ms."""
    tau = as_positive("tau", tau)
    return tau / 5.0, tau / 2.0


#: the longest input record :func:`step_input` and :func:`prbs` build (samples): 10⁷ samples are
#: 14 h at Ts = 5 ms and 80 MB of float64; a longer request is refused up front
MAX_INPUT_SAMPLES = 10_000_000


def _input_samples(duration, Ts):
    """``round(duration / Ts)``, refused (naming duration and Ts) outside 2 … MAX_INPUT_SAMPLES."""
    ratio = duration / Ts
    if not ratio < MAX_INPUT_SAMPLES + 0.5:
        raise ValueError(
            f"duration / Ts = {duration:g} s / {Ts:g} s is more than MAX_INPUT_SAMPLES = "
            f"{MAX_INPUT_SAMPLES} samples; choose a shorter duration or a longer Ts"
        )
    n = int(round(ratio))
    if n < 2:
        raise ValueError(
            f"duration must be at least 2 samples of Ts ({2 * Ts:g} s), got duration={duration:g} s "
            f"with Ts={Ts:g} s"
        )
    return n


def step_input(duration, Ts, amplitude, t_step=0.05, offset=0.0) -> np.ndarray:
    """A voltage step: ``offset`` until ``t_step``, then ``offset + amplitude`` (V per sample).

    Starting at rest before the step keeps the ARX regression well posed and shows the start of the
    transient. ``round(duration / Ts)`` samples.
    """
    duration = as_positive("duration", duration)
    Ts = as_positive("Ts", Ts)
    amplitude = as_real("amplitude", amplitude)
    t_step = as_nonnegative("t_step", t_step)
    offset = as_real("offset", offset)
    n = _input_samples(duration, Ts)
    if t_step >= duration:
        raise ValueError(f"t_step must be < duration ({duration:g} s), got {t_step:g} s")
    u = np.full(n, offset)
    u[np.arange(n) * Ts >= t_step - 1e-12 * Ts] += amplitude
    return u


def prbs(duration, Ts, amplitude, offset=0.0, clock_period=None, nbits=None, seed=0) -> np.ndarray:
    """Pseudo-random binary sequence ``offset ± amplitude`` (V per sample) from a maximum-length LFSR.

    Parameters
    ----------
    duration, Ts : float
        Record length and sample period (s).
    amplitude : float
        Half the distance between the two levels (V, > 0).
    offset : float
        Centre level (V). An offset larger than the friction voltage keeps the motor turning one
        way, which keeps Coulomb friction a constant (and small) bias.
    clock_period : float, optional
        How long each bit is held (s), a whole number of samples; default Ts. A rule of thumb is
        clock_period ≈ tau/2 … tau, so the sequence's power sits under the motor's bandwidth.
    nbits : int, optional
        LFSR length (period 2^nbits - 1 bits); by default the smallest that covers the record.
    seed : int
        Selects the (non-zero) initial LFSR state, so different seeds shift the sequence.
    """
    duration = as_positive("duration", duration)
    Ts = as_positive("Ts", Ts)
    amplitude = as_positive("amplitude", amplitude)
    offset = as_real("offset", offset)
    seed = as_int("seed", seed, minimum=0)
    n = _input_samples(duration, Ts)
    if clock_period is None:
        hold = 1
    else:
        clock_period = as_positive("clock_period", clock_period)
        if clock_period > duration:
            raise ValueError(
                f"clock_period must be <= duration ({duration:g} s), got {clock_period:g} s"
            )
        hold = int(round(clock_period / Ts))
        if hold < 1 or abs(hold * Ts - clock_period) > 1e-6 * clock_period:
            raise ValueError(
                f"clock_period must be a whole multiple of Ts = {Ts:g} s, got {clock_period:g} s"
            )
    nb = -(-n // hold)
    if nbits is None:
        nbits = max(3, int(math.ceil(math.log2(nb + 1))))
        nbits = min(nbits, 32)
    else:
        nbits = as_int("nbits", nbits, minimum=2)
        if nbits > 32:
            raise ValueError(f"nbits must be <= 32, got {nbits}")
    rng = np.random.default_rng(seed)
    state = rng.integers(0, 2, size=nbits)
    if not state.any():
        state[0] = 1
    bits = signal.max_len_seq(nbits, state=state, length=nb)[0]
    levels = offset + amplitude * (2.0 * bits.astype(float) - 1.0)
    return np.repeat(levels, hold)[:n]
