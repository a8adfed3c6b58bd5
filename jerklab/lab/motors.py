"""Hidden per-student motors: a seeded, realistic DC gearmotor for every student ID.

The parameters are drawn from the ranges of small 12 V DC gearmotors (K 15–45 rad/(V·s),
τ 10–60 ms, Coulomb friction 0.1–0.6 V, a small input offset, encoder count noise, a 448 or
896 counts-per-revolution encoder). The seed is ``HMAC-SHA256(key, student ID)``: the same ID
gives the same motor, different IDs give different motors, and without the instructor's key
nobody can regenerate another student's motor.

The key comes from ``$JERKLAB_INSTRUCTOR_KEY``, else the file named by
``$JERKLAB_INSTRUCTOR_KEY_FILE``, else ``~/.config/jerklab/instructor.key``. Without any, the
documented :data:`CLASSROOM_DEFAULT_KEY` is used with a warning: it is *not* secret.

Two kinds of motor come from here:

* a **graded** motor, seeded by the instructor's key: it lives only in a trusted process (the
  class rig service, :mod:`jerklab.lab.service`, or the instructor's own grader), never in a
  student's kernel;
* a **practice** motor (:func:`practice_motor`), seeded by a public class code
  (:func:`practice_key`): what a student gets without a class rig service. Anyone can
  regenerate it, so practice work is checked against the student's own recordings, never
  against its parameters.

The true values never appear in a ``repr``, in rig metadata or in a recording; they are read
only by trusted code (:func:`hidden_truth`, which the service and the grader hand to the
checks).

The rig knows no student: the lab builds the student's device (:func:`student_device`: the
hidden motor, its encoder count noise) and hands it to :func:`jerklab.rig.connect`, with the
student ID as the recordings' caller metadata (:func:`connect_student`).
"""

from __future__ import annotations

import hashlib
import hmac
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jerklab import paper
from jerklab.lab.specs import hidden_ranges
from jerklab.plant import DCMotor, FlexibleDCMotor
from jerklab.rig import Device, connect, load_profile
from jerklab.rig.flexload import DESIGN_RANGE, RulerLoad, predict

__all__ = [
    "CLASSROOM_DEFAULT_KEY",
    "RANGES",
    "MODE_RANGES",
    "ranges",
    "StudentMotor",
    "StudentFlexibleMotor",
    "student_motor",
    "hidden_truth",
    "motor_from_truth",
    "simulated_motor",
    "student_device",
    "instructor_key",
    "normalize_student",
    "connect_student",
    "DefaultKeyWarning",
    "PRACTICE_CODE",
    "practice_key",
    "practice_motor",
]

#: Used when no instructor key is set. Public (it is in the source): fine for practice, not for marks.
CLASSROOM_DEFAULT_KEY = b"jerklab-classroom-default-key (not secret)"

#: The distribution every hidden motor of the paper's class is drawn from (uniform in log for K
#: and tau): K 15-45 rad/(V s), tau 10-60 ms, Coulomb friction 0.1-0.6 V and an input offset
#: within +-0.08 V (below the smallest friction: no creep at 0 V), input referred, encoder count
#: noise 0-0.5 counts (standard deviation), 448 or 896 counts per output revolution (x1). Another
#: rig's motors: :func:`ranges` of its profile (jerklab.lab.specs.hidden_ranges).
RANGES = hidden_ranges("paper")
SUPPLY_VOLTAGE = paper.SUPPLY_VOLTAGE


def ranges(profile=None) -> dict:
    """The distribution of the hidden motors on a rig with ``profile``'s motor (None: the
    paper's class, :data:`RANGES`): :func:`jerklab.lab.specs.hidden_ranges`."""
    return RANGES if profile is None else hidden_ranges(profile)


#: The hidden load mode of a flexible student motor (``student_motor(..., plant="flexible")``): the
#: shaft's own mode (motor held still) uniform in log frequency, its damping uniform, drawn
#: with a separate HMAC purpose so the rigid motor of a student does not change. The load is
#: 0.3 of the motor's inertia, so the mode shows on the motor's encoder; the coupled mode the
#: encoder sees (``hidden_truth``: ``mode_hz``, ``mode_zeta``) is then a little stiffer and better damped.
MODE_RANGES = {
    "mode_hz": (7.0, 15.0),  # Hz, the shaft mode with the motor held still
    "mode_damping": (0.01, 0.04),  # damping ratio of the shaft
    "load_ratio": (0.3, 0.3),  # J_load / J_motor
}

#: The class code of practice motors when none is given (``$JERKLAB_CLASS_CODE`` sets another).
PRACTICE_CODE = "practice"

_ID_RE = re.compile(r"^[A-Za-z0-9._@+-]{1,64}$")


class DefaultKeyWarning(UserWarning):
    """No instructor key is set: the classroom default key (public) seeds the motors."""


def normalize_student(student) -> str:
    """The canonical form of a student ID (stripped, lower case); ValueError naming ``student``."""
    if not isinstance(student, str):
        raise TypeError(f"student must be a string ID, got {type(student).__name__}")
    s = student.strip().lower()
    if not _ID_RE.match(s):
        raise ValueError(
            f"student must be 1-64 characters of letters, digits and ._@+-, got {student!r}"
        )
    return s


def instructor_key(warn: bool = True) -> tuple[bytes, str]:
    """The key that enters every seed, and where it came from ("env", "file", "default")."""
    env = os.environ.get("JERKLAB_INSTRUCTOR_KEY")
    if env:
        return env.encode(), "env"
    path = os.environ.get("JERKLAB_INSTRUCTOR_KEY_FILE")
    candidates = [Path(path)] if path else [Path.home() / ".config" / "jerklab" / "instructor.key"]
    for p in candidates:
        if p.is_file():
            key = p.read_bytes().strip()
            if key:
                return key, "file"
        elif path:
            raise ValueError(f"JERKLAB_INSTRUCTOR_KEY_FILE names {path!r}, which is not a file")
    if warn:
        warnings.warn(
            "no instructor key set (JERKLAB_INSTRUCTOR_KEY or a key file): using the "
            "classroom default key, which is public — anyone can regenerate any motor. "
            "Fine for practice, not for graded work.",
            DefaultKeyWarning,
            stacklevel=3,
        )
    return CLASSROOM_DEFAULT_KEY, "default"


def practice_key(class_code: str | None = None) -> bytes:
    """The public key of the practice motors of ``class_code`` (default ``$JERKLAB_CLASS_CODE``,
    else :data:`PRACTICE_CODE`, whose key is :data:`CLASSROOM_DEFAULT_KEY`).

    A class code is public (the instructor hands it out so that a class practises on the same
    family of motors): the practice motors it seeds are not secret, and differ from the graded
    motors, which the instructor's key seeds.
    """
    code = class_code if class_code is not None else os.environ.get("JERKLAB_CLASS_CODE")
    code = PRACTICE_CODE if code is None else code
    if not isinstance(code, str) or not re.fullmatch(r"[A-Za-z0-9._@+-]{1,64}", code.strip()):
        raise ValueError(
            f"class_code must be 1-64 characters of letters, digits and ._@+-, got {code!r}"
        )
    code = code.strip().lower()
    if code == PRACTICE_CODE:
        return CLASSROOM_DEFAULT_KEY
    return f"jerklab-practice-class-code:{code}".encode()


def practice_motor(student, class_code: str | None = None, plant: str = "rigid"):
    """The practice motor of ``student`` for ``class_code`` (see :func:`practice_key`): public,
    for working without a class rig service; never the student's graded motor."""
    return student_motor(student, key=practice_key(class_code), plant=plant)


def _seed(student: str, key: bytes, purpose: str = "motor-v1") -> int:
    digest = hmac.new(key, f"jerklab:{purpose}:{student}".encode(), hashlib.sha256).digest()
    return int.from_bytes(digest[:16], "little")


@dataclass(frozen=True, repr=False)
class _Parameters:
    K: float
    tau: float
    coulomb_friction: float
    offset: float
    noise_counts: float
    encoder_ppr: int

    def __repr__(self):
        return "_Parameters(hidden)"


def _draw(seed: int, ranges_=None) -> _Parameters:
    R = RANGES if ranges_ is None else ranges_
    rng = np.random.default_rng(seed)
    lo, hi = R["K"]
    K = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    lo, hi = R["tau"]
    tau = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    fc = float(rng.uniform(*R["coulomb_friction"]))
    off = float(rng.uniform(*R["offset"]))
    noise = float(rng.uniform(*R["noise_counts"]))
    ppr = int(rng.choice(R["encoder_ppr"]))
    return _Parameters(K, tau, fc, off, noise, ppr)


class StudentMotor(DCMotor):
    """A :class:`jerklab.plant.DCMotor` with hidden parameters.

    DCMotor's input offset (the motor sees ``u + offset``, a driver asymmetry, input referred,
    V), Coulomb friction, PWM and encoder quantization; the virtual rig adds encoder count noise
    (:func:`student_device`). No dead zone: at steady state it is indistinguishable from the
    Coulomb friction, so lab 1 could not separate the two. ``repr`` never shows a value.
    Make one with :func:`student_motor`.
    """

    def __init__(self, student, params: _Parameters, seed: int, supply_voltage=SUPPLY_VOLTAGE):
        super().__init__(
            K=params.K,
            tau=params.tau,
            supply_voltage=supply_voltage,
            pwm_bits=10,
            encoder_ppr=params.encoder_ppr,
            decoding=1,
            coulomb_friction=params.coulomb_friction,
            noise_std=0.0,
            seed=seed % 2**32,
            offset=params.offset,
        )
        self.student = student
        self.noise_counts = params.noise_counts

    def __repr__(self):
        return f"StudentMotor(student={self.student!r}, parameters hidden)"

    __str__ = __repr__


def student_motor(
    student, key: bytes | None = None, plant: str = "rigid", profile=None
) -> StudentMotor:
    """The hidden motor of ``student`` (same ID and key -> same motor).

    Parameters
    ----------
    student : str
        Student ID (case and surrounding spaces ignored).
    key : bytes, optional
        Instructor key; default :func:`instructor_key` (environment or key file).
    plant : "rigid" or "flexible"
        ``"flexible"``: the same K, τ and encoder driving a load with a hidden mode
        (:class:`StudentFlexibleMotor`, seeded by the same key and ID).
    profile : str, path or jerklab.rig.MotorProfile, optional
        The rig's motor (:mod:`jerklab.rig.profiles`): the hidden motor is drawn from
        :func:`ranges` of it, on its supply (None: the paper's class, :data:`RANGES`).
    """
    sid = normalize_student(student)
    if plant not in ("rigid", "flexible", None):
        raise ValueError(f"plant must be 'rigid' or 'flexible', got {plant!r}")
    if key is None:
        key, _ = instructor_key()
    seed = _seed(sid, bytes(key))
    prof = None if profile is None else load_profile(profile)
    params = _draw(seed, ranges(prof))
    if plant == "flexible":
        mode_seed = _seed(sid, bytes(key), "mode-v1")
        if prof is not None and (prof.datasheet or {}).get("stall_current"):
            params, mode = _draw_load(mode_seed, prof, params)
        else:
            mode = _draw_mode(mode_seed)
        return StudentFlexibleMotor(sid, params, seed, mode)
    if prof is None:
        return StudentMotor(sid, params, seed)
    return StudentMotor(sid, params, seed, supply_voltage=prof.supply_voltage)


def hidden_truth(motor) -> dict:
    """The true values of a hidden motor, for the checks only (never print them).

    Plain data: ``K``, ``tau``, ``coulomb_friction``, ``offset``, ``counts_per_rev``,
    ``noise_counts`` and ``seed`` (enough to rebuild the motor, :func:`motor_from_truth`) and,
    for a flexible load, the coupled mode the encoder sees (``mode_hz``, ``mode_zeta``) and the
    shaft's (``mode_frequency`` rad/s, ``mode_damping``, ``load_ratio``).
    """
    truth = {
        "K": motor.K,
        "tau": motor.tau,
        "coulomb_friction": motor.coulomb_friction,
        "offset": getattr(motor, "offset", 0.0),
        "counts_per_rev": motor.encoder_ppr * motor.decoding,
        "noise_counts": float(getattr(motor, "noise_counts", 0.0)),
        "seed": motor.seed,
    }
    if isinstance(motor, FlexibleDCMotor):
        truth["mode_hz"], truth["mode_zeta"] = coupled_mode(motor)
        truth.update(
            mode_frequency=motor.mode_frequency,
            mode_damping=motor.mode_damping,
            load_ratio=motor.load_ratio,
        )
    return truth


def motor_from_truth(truth: dict):
    """The hidden motor :func:`hidden_truth` describes (the same parameters and seed): a
    :class:`StudentMotor`, or a :class:`StudentFlexibleMotor` when ``truth`` has a mode."""
    params = _Parameters(
        truth["K"],
        truth["tau"],
        truth["coulomb_friction"],
        truth["offset"],
        truth["noise_counts"],
        truth["counts_per_rev"],
    )
    if "mode_frequency" in truth:
        mode = (
            truth["mode_frequency"] / (2.0 * math.pi),
            truth["mode_damping"],
            truth["load_ratio"],
        )
        return StudentFlexibleMotor(None, params, truth["seed"], mode)
    return StudentMotor(None, params, truth["seed"])


def _draw_mode(seed: int) -> tuple[float, float, float]:
    rng = np.random.default_rng(seed)
    lo, hi = MODE_RANGES["mode_hz"]
    f = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    z = float(rng.uniform(*MODE_RANGES["mode_damping"]))
    lr = float(rng.uniform(*MODE_RANGES["load_ratio"]))
    return f, z, lr


def _draw_load(seed: int, prof, params: _Parameters):
    """A hidden load of the flexible-load design (:mod:`jerklab.rig.flexload`: a steel rule with
    a tip mass) on ``prof``'s motor: free length and tip mass uniform in log over
    ``DESIGN_RANGE``, the damping uniform over ``MODE_RANGES``; the two-mass model predicted
    from them, the loaded τ in the parameters. Returns (parameters, (f Hz, ζ, J_l/J_m))."""
    rng = np.random.default_rng(seed)
    L = float(math.exp(rng.uniform(*np.log(DESIGN_RANGE["length"]))))
    M = float(math.exp(rng.uniform(*np.log(DESIGN_RANGE["tip_mass"]))))
    z = float(rng.uniform(*MODE_RANGES["mode_damping"]))
    r = predict(
        RulerLoad(length=L, tip_mass=M, damping=z), prof.replace(K=params.K, tau=params.tau)
    )
    loaded = _Parameters(
        params.K,
        r["tau"],
        params.coulomb_friction,
        params.offset,
        params.noise_counts,
        params.encoder_ppr,
    )
    return loaded, (r["mode_hz"], z, r["load_ratio"])


class StudentFlexibleMotor(FlexibleDCMotor):
    """A student's hidden motor (K, τ, encoder of :class:`StudentMotor`) driving a load through
    a compliant shaft with a hidden mode (:data:`MODE_RANGES`). The two-mass model has no
    Coulomb friction or offset (``jerklab.plant.FlexibleDCMotor``); the rig adds the encoder
    count noise. ``repr`` never shows a value. Make one with :func:`student_motor` ``(...,
    plant="flexible")``."""

    def __init__(self, student, params: _Parameters, seed: int, mode: tuple[float, float, float]):
        f, z, lr = mode
        super().__init__(
            K=params.K,
            tau=params.tau,
            load_ratio=lr,
            mode_frequency=2.0 * math.pi * f,
            mode_damping=z,
            supply_voltage=SUPPLY_VOLTAGE,
            pwm_bits=10,
            encoder_ppr=params.encoder_ppr,
            decoding=1,
            seed=seed % 2**32,
        )
        self.student = student
        self.noise_counts = params.noise_counts

    def __repr__(self):
        return f"StudentFlexibleMotor(student={self.student!r}, parameters hidden)"

    __str__ = __repr__


def coupled_mode(motor) -> tuple[float, float]:
    """The lightly damped mode the motor's encoder sees: (frequency Hz, damping ratio) of the
    complex pole pair of a :class:`jerklab.plant.FlexibleDCMotor`'s state matrix."""
    A, _ = motor._matrices()
    ev = np.linalg.eigvals(A)
    ev = ev[np.abs(ev.imag) > 0]
    if ev.size == 0:
        raise ValueError("the motor has no oscillatory mode")
    p = ev[np.argmax(ev.imag)]
    return float(abs(p) / (2.0 * math.pi)), float(-p.real / abs(p))


def simulated_motor(motor, port=None):
    """The hidden motor as ``port`` simulates it, or None for a real board (its motor is real).

    The virtual rig (``port`` None or ``"virtual"``) runs ``motor`` itself. ``"simavr"`` runs
    the firmware, whose encoder is the paper's 448 counts (x1) and whose plant has no input
    offset or count noise: the same K, τ, friction (or load mode) with those.
    """
    if port in (None, "virtual"):
        return motor
    if port != "simavr":
        return None
    params = _Parameters(motor.K, motor.tau, motor.coulomb_friction, 0.0, 0.0, paper.ENCODER_PPR)
    if isinstance(motor, StudentFlexibleMotor):  # the two-mass model has no friction
        mode = (motor.mode_frequency / (2.0 * math.pi), motor.mode_damping, motor.load_ratio)
        return StudentFlexibleMotor(motor.student, params, motor.seed, mode)
    return StudentMotor(motor.student, params, motor.seed)


def student_device(motor, speed=None) -> Device:
    """The simulated device of a hidden motor for :func:`jerklab.rig.connect`: the motor and
    its encoder count noise (seeded by the motor's seed), at ``speed`` times real time (virtual
    rig only; None: as fast as possible)."""
    noise = float(getattr(motor, "noise_counts", 0.0))
    return Device(
        motor,
        speed=speed,
        count_noise=noise,
        noise_seed=(motor.seed % 2**63, 1) if noise else None,
    )


def connect_student(student, port=None, *, key=None, plant="rigid", speed=None, **options):
    """A rig for ``student``: the virtual rig (``port`` None) or ``"simavr"`` with the student's
    hidden motor (``plant="flexible"``: with its hidden load mode); any other port is a real
    board (its motor is the real one).

    ``options`` go to :func:`jerklab.rig.connect` (``link``, ``progress``, ``recordings``,
    ``model``); every recording carries ``{"student": ID}`` in its caller metadata. The rig
    holds no truth: :func:`student_motor` (with the key) gives the hidden motor.
    """
    sid = normalize_student(student)
    hidden = simulated_motor(student_motor(sid, key, plant=plant), port)
    if hidden is None:
        if speed is not None:
            raise ValueError("speed applies to the virtual rig only (port=None)")
        device = None
    else:
        device = student_device(hidden, speed)
    metadata = dict(options.pop("metadata", None) or {}, student=sid)
    return connect(port, device=device, metadata=metadata, **options)
