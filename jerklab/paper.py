"""The numbers of the papers, in one place: the motor and rig, the default limits, Table I.

Every default in jerklab that comes from a paper should refer to a name here, so that a
value is written once and its source is stated once. SI units unless the name says
otherwise (the piezo model keeps the paper's V → µm and Hz, the FPGA set-up its integer
µm/s, Hz and clock counts). Derivations and the papers' errors: ``docs/THEORY.md``.

Sources (ASCII spellings for grep: Stojcic, Xu & Meckl, Yang)
-------------------------------------------------------------
* M. J. Stojčić, "Design and implementation of a digital positioning system with controlled
  jerk", Facta Universitatis, 2015 (§4A: the identified motor, the encoder and the sampling
  time; §4B: the PWM and the Arduino Uno).
* Y. Xu, P. H. Meckl, "Robust time-optimal command shaping for piezoelectric actuators: STM
  application" (Table I: the linear PZT model of Xu & Meckl eq. 1; the 0.2 ms sampling time;
  the 0.2 % CNIA tolerance of their Fig. 2).
* G. Yang, Z. Ye, Y. Pan, Z. Ma, "The implementation of S-curve acceleration and deceleration
  using FPGA", TELKOMNIKA 11(1), 2013 (§3: the test set-up of Yang eqs. 7, 8).

Examples
--------
>>> from jerklab import paper
>>> paper.MOTOR_K, paper.MOTOR_TAU, paper.TS
(32.4, 0.025, 0.005)
>>> round(paper.COUNTS_PER_RAD, 3)
71.301
"""

from __future__ import annotations

import math
from types import MappingProxyType

__all__ = [
    "MOTOR_K",
    "MOTOR_TAU",
    "SUPPLY_VOLTAGE",
    "PWM_BITS",
    "PWM_MAX",
    "PWM_FREQUENCY",
    "MCU_CLOCK_HZ",
    "ENCODER_PPR",
    "ENCODER_DECODING",
    "COUNTS_PER_RAD",
    "TS",
    "ZETA",
    "SIGMA_RATIO",
    "MAX_JERK",
    "MAX_ACCEL",
    "MAX_VELOCITY",
    "LIMITS",
    "PIEZO_TABLE_I",
    "PIEZO_TS",
    "CNIA_EPS_FRACTION",
    "YANG_SETUP",
]

# ----------------------------------------------------------------------------------------------
# Stojčić (Stojcic) 2015: the motor and the rig
# ----------------------------------------------------------------------------------------------
#: Static gain K of P(s) = K/(s(τs + 1)) (Stojčić eq. 1), rad/(V·s), identified in §4A.
MOTOR_K = 32.4

#: Mechanical time constant τ of Stojčić eq. 1, s, identified in §4A.
MOTOR_TAU = 0.025

#: Motor supply of the L298 H-bridge, V. §4B gives a 12–30 V range; the rig uses its low end,
#: which is also the output clamp of the controller (the paper has none).
SUPPLY_VOLTAGE = 12.0

#: PWM resolution, bits (§4B: "10-bit PWM"; it is Timer 1, 16-bit, not Timer 2 as printed).
PWM_BITS = 10

#: Full-scale PWM duty in ticks: TOP of the phase-correct 10-bit mode.
PWM_MAX = 2**PWM_BITS - 1

#: Clock of the ATmega328P on the Arduino Uno, Hz.
MCU_CLOCK_HZ = 16_000_000

#: Phase-correct PWM with no prescaler counts up and down: f = f_clk / (2 TOP) ≈ 7.82 kHz,
#: the paper's "8 kHz", Hz.
PWM_FREQUENCY = MCU_CLOCK_HZ / (2 * PWM_MAX)

#: Encoder pulses per revolution of one channel (§4A: N_c = 448).
ENCODER_PPR = 448

#: Edges counted per pulse: 1, channel A counts and channel B gives the direction (§4A).
ENCODER_DECODING = 1

#: Encoder counts per radian with the paper's decoding, 448/(2π) ≈ 71.3.
COUNTS_PER_RAD = ENCODER_PPR * ENCODER_DECODING / (2.0 * math.pi)

#: Sampling time T_s, s (§4A: τ/(2…5) = 5 ms).
TS = 0.005

#: Damping ratio of the dominant pole pair of Stojčić eq. 11 (§3B: ζ = 1, no overshoot).
ZETA = 1.0

#: Real pole σ as a multiple of ω_n (§3B: σ ≥ 7 ω_n; the paper never states ω_n itself).
SIGMA_RATIO = 7.0

# ----------------------------------------------------------------------------------------------
# default limits of a move (jerk J, acceleration E, velocity Ω of Stojčić eq. 4)
# ----------------------------------------------------------------------------------------------
# The paper gives no numbers for J, E, Ω. These are the rig's defaults (firmware
# jl_device.h, the virtual rig, Rig.configure): a 10π rad move at these limits is the
# example where the published planner is slowest against Ruckig (docs/THEORY.md).

#: Peak jerk J, rad/s³.
MAX_JERK = 2e4

#: Acceleration limit E, rad/s².
MAX_ACCEL = 300.0

#: Velocity limit Ω, rad/s (955 rpm; in steady state Ω/K = 3.1 V of the 12 V supply, whose
#: no-load speed K·12 V is 389 rad/s).
MAX_VELOCITY = 100.0

#: ``(MAX_JERK, MAX_ACCEL, MAX_VELOCITY)``, the order of ``SetLimits`` and ``plan_*``.
LIMITS = (MAX_JERK, MAX_ACCEL, MAX_VELOCITY)

# ----------------------------------------------------------------------------------------------
# Xu & Meckl: the PZT actuator
# ----------------------------------------------------------------------------------------------
#: Xu & Meckl Table I, the linear PZT dynamics of Xu & Meckl eq. 1 (V → µm, frequencies in Hz):
#: NMP zero ζ_z = 0.70 at 1643 Hz, first mode ζ_1 = 0.008 at 242 Hz, second mode ζ_2 = 0.39 at
#: 777 Hz, gain K = 97000. Read-only.
PIEZO_TABLE_I = MappingProxyType(
    {
        "K": 97000.0,
        "zeta_z": 0.70,
        "f_z": 1643.0,
        "zeta_1": 0.008,
        "f_1": 242.0,
        "zeta_2": 0.39,
        "f_2": 777.0,
    }
)

#: Sampling time of the Xu & Meckl simulation study, s (0.2 ms).
PIEZO_TS = 2e-4

#: CNIA stopping threshold ε of Xu & Meckl eq. 2 as a fraction of the input range (0.2 %, Fig. 2).
CNIA_EPS_FRACTION = 0.002

# ----------------------------------------------------------------------------------------------
# Yang et al. 2013: the FPGA test set-up (integer units of the hardware)
# ----------------------------------------------------------------------------------------------
#: Yang §3: V = 20 mm/s = 20000 µm/s, acceleration and cruise 1 s each, refresh period
#: t_c = 200 µs, 50 MHz clock, k = 20 µm per pulse (reading v = k·f), first count
#: PWM_INITAL_COUNT = 300. Keyword arguments of ``jerklab.fpga.YangSCurve``. Read-only.
YANG_SETUP = MappingProxyType(
    dict(
        max_velocity=20000,
        accel_time=1.0,
        cruise_time=1.0,
        refresh_period=200e-6,
        clock_hz=50_000_000,
        step_um=20,
        start_count=300,
    )
)
