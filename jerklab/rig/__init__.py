"""The jerk-control rig: a real Uno, the firmware on simavr, or a virtual rig — one API.

>>> from jerklab.rig import connect
>>> rig = connect()                      # virtual rig (a simulated motor), no hardware needed
>>> rig.name, rig.is_virtual
('jerklab-virtual', True)
>>> rig.close()

``connect("/dev/ttyACM0")`` opens a board, ``connect("socket://192.168.1.50:5000")`` one on
the network (the paper's Ethernet set-up), ``connect("simavr")`` the real firmware on a
simulated ATmega328P.  Then ``rig.step(voltage, seconds)`` and ``rig.run_move(profile,
gains, Ts=0.005)`` return a :class:`Recording` that is written to disk while it arrives.

``python -m jerklab.rig serve`` puts the virtual rig on a pseudo-terminal so any serial
client can talk to it as to a board.
"""

from __future__ import annotations

import importlib
import os
import sys

from jerklab import paper
from jerklab._validate import as_positive
from jerklab.rig.client import (
    PortBusyError,
    Rig,
    RigBusyError,
    RigCommandError,
    RigConnectionError,
    RigError,
    RigRunError,
    RigTimeoutError,
    UnknownPortError,
    UnstableDesignError,
)
from jerklab.rig.recording import Recording, compare, plot_comparison, recordings_dir
from jerklab.rig.virtual import VirtualDevice, VirtualSerial

__all__ = [
    "connect",
    "Rig",
    "Recording",
    "recordings_dir",
    "compare",
    "plot_comparison",
    "VirtualDevice",
    "VirtualSerial",
    "RigError",
    "RigConnectionError",
    "RigTimeoutError",
    "RigCommandError",
    "RigRunError",
    "UnknownPortError",
    "PortBusyError",
    "RigBusyError",
    "UnstableDesignError",
    "list_ports",
    "BAUDRATE",
]

BAUDRATE = 115200
#: the shortest reply ``timeout`` / ``hello_timeout`` accepted (s): an ACK frame takes about 1 ms at
#: 115 200 baud, so a shorter wait cannot be met by any rig
MIN_TIMEOUT = 1e-3
_VIRTUAL_NAMES = (None, "virtual")
_URL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "alt", "hwgrep", "cp2110")


def list_ports(include_all=False) -> list:
    """Serial ports that may have a rig behind them, likely Arduinos first
    (see :func:`jerklab.rig.ports.list_ports`; ``python -m jerklab.rig ports`` prints them)."""
    from jerklab.rig.ports import list_ports as _list

    return _list(include_all=include_all)


def connect(
    port=None,
    *,
    student=None,
    motor=None,
    plant=None,
    speed=None,
    timeout=2.0,
    hello_timeout=None,
    progress=True,
    recordings=None,
    supply_voltage=None,
    counts_per_rev=None,
    model=(paper.MOTOR_K, paper.MOTOR_TAU),
    baudrate=BAUDRATE,
    **link_options,
) -> Rig:
    """Connect to a rig and return a :class:`Rig`.

    Parameters
    ----------
    port : None, str or path
        ``None`` (or ``"virtual"``): the in-process virtual rig (``VirtualDevice`` driving a
        ``jerklab.plant.DCMotor``). ``"simavr"``: the firmware ELF on a simulated Uno
        (``jerklab.rig.simavr.launch()``). Anything else: a device path (``/dev/ttyACM0``,
        ``COM3``, a ``/dev/pts/N`` from ``python -m jerklab.rig serve``) or a pyserial URL
        (``socket://host:port``, ``loop://``, ``rfc2217://...``).
    student : str, optional
        A student ID: the virtual rig (or ``"simavr"``) gets that student's hidden motor,
        drawn by ``jerklab.lab.student_motor`` (seeded with the instructor key); with a real
        port the ID is only remembered (``rig.student``). Not together with ``motor``.
    motor : jerklab.plant.DCMotor, optional
        The simulated motor of the virtual rig or of ``"simavr"`` (default: the paper's,
        K = 32.4 rad/(V s), tau = 25 ms); not allowed for a real port. A
        ``jerklab.plant.FlexibleDCMotor`` gives a flexible load.
    plant : None, "rigid" or "flexible"
        ``"flexible"``: the simulated motor drives its load through a compliant shaft
        (``jerklab.plant.FlexibleDCMotor``, the encoder on the motor): the paper's motor with
        an 8 Hz load mode, or with ``student`` that student's motor with a hidden mode
        (``jerklab.lab.motors``). Virtual rig and ``"simavr"`` only.
    speed : float or None
        Virtual rig only: ``None`` as fast as possible, else that many times real time.
    timeout : float
        Seconds to wait for a reply or the next telemetry frame.
    hello_timeout : float
        Seconds to keep saying HELLO (every 0.25 s) after opening (default 3 s for a port — an
        Uno reboots when the port opens and its bootloader listens for about 1 s — 1 s for the
        virtual rig).
    progress : bool
        Progress bar during runs: an ipywidgets bar inside a Jupyter kernel, text in a terminal,
        nothing when False.
    recordings : path
        Folder for recordings (default ``$JERKLAB_RECORDINGS`` or ``./recordings``).
    supply_voltage, counts_per_rev : float, int
        The rig's H-bridge supply (V) and encoder counts per revolution (default: the virtual
        motor's, else 12 V and 448).
    model : (K, tau)
        Motor model for the feedforward until you call ``rig.set_model`` (paper's values).
    baudrate : int
        Serial speed (115200, as the firmware).

    A device path is opened exclusively (pyserial ``exclusive=True`` on POSIX) and locked
    with a lock file naming this process (:class:`jerklab.rig.ports.PortLock`) until
    ``rig.close()``.

    Raises
    ------
    UnknownPortError
        ``port`` is malformed (empty, blank, not a string), does not exist, is not a known
        pyserial URL, or cannot be opened (permissions: the ``dialout`` group); the message
        names it.
    PortBusyError
        Another program holds the port; the message names it (pid, host, program).
    RigTimeoutError
        The port opened but no jerklab rig answered HELLO; the message says what was tried
        and what to check.
    ValueError
        ``timeout`` or ``hello_timeout`` not a number >= ``MIN_TIMEOUT`` (1 ms).
    """
    for name, value in (("timeout", timeout), ("hello_timeout", hello_timeout)):
        if value is not None and as_positive(name, value) < MIN_TIMEOUT:
            raise ValueError(
                f"{name} must be >= MIN_TIMEOUT = {MIN_TIMEOUT:g} s (one frame at {BAUDRATE} baud), "
                f"got {value!r}"
            )
    if plant not in (None, "rigid", "flexible"):
        raise ValueError(f"plant must be None, 'rigid' or 'flexible', got {plant!r}")
    if plant == "flexible" and port not in _VIRTUAL_NAMES and port != "simavr":
        raise ValueError(
            "plant='flexible' applies to the virtual rig (port=None) and 'simavr' only"
        )
    if plant == "flexible" and motor is not None:
        raise ValueError("give either plant='flexible' or motor (a FlexibleDCMotor), not both")
    if student is not None:
        if motor is not None:
            raise ValueError("give either student (a hidden motor) or motor, not both")
        from jerklab.lab.motors import connect_student

        if plant == "flexible":
            link_options = dict(link_options, plant="flexible")
        opts = dict(
            link_options,
            speed=speed,
            timeout=timeout,
            hello_timeout=hello_timeout,
            progress=progress,
            recordings=recordings,
            model=model,
        )
        if port not in _VIRTUAL_NAMES:
            if speed is not None:
                raise ValueError("speed applies to the virtual rig only (port=None)")
            opts.pop("speed")
            opts.update(
                supply_voltage=supply_voltage, counts_per_rev=counts_per_rev, baudrate=baudrate
            )
        return connect_student(student, port, **opts)
    if plant == "flexible":
        from jerklab.plant import FlexibleDCMotor

        motor = FlexibleDCMotor()
    if port in _VIRTUAL_NAMES:
        from jerklab.plant import DCMotor

        motor = DCMotor() if motor is None else motor
        link = VirtualSerial(VirtualDevice(motor), speed=speed, timeout=0.05)
        return Rig(
            link,
            "virtual",
            supply_voltage=motor.supply_voltage if supply_voltage is None else supply_voltage,
            counts_per_rev=(
                motor.encoder_ppr * motor.decoding if counts_per_rev is None else counts_per_rev
            ),
            model=model,
            timeout=timeout,
            hello_timeout=hello_timeout or 1.0,
            progress=progress,
            recordings=recordings,
        )
    port = _check_port(port)
    if speed is not None:
        raise ValueError("speed applies to the virtual rig only (port=None)")
    if motor is not None and port != "simavr":
        raise ValueError("motor applies to the virtual rig (port=None) and 'simavr' only")
    on_close = None
    if port == "simavr":
        launcher = _launch_simavr(motor)
        port, on_close = launcher.port, launcher.close
        if motor is not None:
            supply_voltage = motor.supply_voltage if supply_voltage is None else supply_voltage
            counts_per_rev = (
                motor.encoder_ppr * motor.decoding if counts_per_rev is None else counts_per_rev
            )
    lock = None
    try:
        if "://" not in port:
            from jerklab.rig.ports import PortLock

            lock = PortLock(port).acquire()
        link = _open_serial(port, baudrate, link_options)
    except BaseException:
        if lock is not None:
            lock.release()
        if on_close is not None:
            on_close()
        raise
    if lock is not None:
        on_close = _chain(lock.release, on_close)
    return Rig(
        link,
        port,
        supply_voltage=paper.SUPPLY_VOLTAGE if supply_voltage is None else supply_voltage,
        counts_per_rev=(
            paper.ENCODER_PPR * paper.ENCODER_DECODING if counts_per_rev is None else counts_per_rev
        ),
        model=model,
        timeout=timeout,
        hello_timeout=hello_timeout or 3.0,
        progress=progress,
        recordings=recordings,
        on_close=on_close,
    )


def _chain(first, then):
    def close():
        try:
            first()
        finally:
            if then is not None:
                then()

    return close


def _check_port(port) -> str:
    """``port`` as a string, or an error naming the parameter and what was wrong with it."""
    if isinstance(port, os.PathLike):
        port = os.fspath(port)
    if isinstance(port, bytes):
        raise UnknownPortError(
            f"port must be a str (a device path or a pyserial URL), got bytes {port!r}: "
            "decode it first"
        )
    if not isinstance(port, str):
        raise UnknownPortError(
            f"port must be None (the virtual rig), 'simavr', a device path or a pyserial "
            f"URL, got {port!r} ({type(port).__name__})"
        )
    if port == "":
        raise UnknownPortError(
            "port must not be empty: use None for the virtual rig, 'simavr', a device "
            "path such as '/dev/ttyACM0' or 'COM3' (python -m jerklab.rig ports lists "
            "candidates), or a pyserial URL such as 'socket://host:5000'"
        )
    if not port.strip():
        raise UnknownPortError(f"port must not be blank, got {port!r}")
    if port != port.strip():
        raise UnknownPortError(
            f"port has leading or trailing whitespace: {port!r} (did you mean {port.strip()!r}?)"
        )
    if "\0" in port:
        raise UnknownPortError(f"port must not contain a NUL byte, got {port!r}")
    if "://" in port:
        scheme = port.split("://", 1)[0]
        if scheme not in _URL_SCHEMES:
            raise UnknownPortError(
                f"port {port!r} is not a known pyserial URL: the scheme {scheme!r} is not "
                f"one of {', '.join(s + '://' for s in _URL_SCHEMES)}"
            )
    elif port != "simavr" and not _is_windows_com(port) and not os.path.exists(port):
        hint = ""
        dev = os.path.join("/dev", port)
        if os.sep not in port and os.path.exists(dev):
            hint = f" (did you mean {dev!r}?)"
        else:
            try:
                found = [r["device"] for r in list_ports()]
            except Exception:
                found = []
            hint = (
                f"; ports found: {', '.join(found)}"
                if found
                else "; no USB serial port found: is the board plugged in?"
            )
        raise UnknownPortError(
            f"port {port!r} does not exist{hint} (python -m jerklab.rig ports lists candidates)"
        )
    return port


def _is_windows_com(port: str) -> bool:
    import re
    import sys

    return (
        sys.platform.startswith("win")
        and re.fullmatch(r"(\\\\\.\\)?COM\d+", port, re.I) is not None
    )


def _open_serial(port, baudrate, options):
    import serial

    kwargs = dict(baudrate=baudrate, timeout=0.05, write_timeout=2.0)
    if "://" not in port and os.name == "posix":
        kwargs["exclusive"] = True  # TIOCEXCL + flock: a second open fails
    kwargs.update(options)
    try:
        link = serial.serial_for_url(port, **kwargs)
    except PermissionError as exc:
        raise UnknownPortError(_permission_message(port, exc)) from exc
    except (serial.SerialException, OSError, ValueError) as exc:
        if (
            isinstance(exc.__context__, PermissionError)
            or getattr(exc, "errno", None) == 13
            or "Permission denied" in str(exc)
        ):
            raise UnknownPortError(_permission_message(port, exc)) from exc
        if "exclusively lock" in str(exc) or getattr(exc, "errno", None) in (11, 16):
            from jerklab.rig.ports import port_holders

            who = (
                "; ".join(f"pid {pid} ({cmd})" for pid, cmd in port_holders(port))
                or "another program"
            )
            raise PortBusyError(f"port {port!r} is in use by {who}: {exc}", port=port) from exc
        raise UnknownPortError(f"cannot open rig port {port!r}: {exc}") from exc
    try:
        link.reset_input_buffer()
    except Exception:
        pass
    return link


def _permission_message(port, exc):
    import getpass

    return (
        f"cannot open rig port {port!r}: permission denied ({exc}). On Linux add yourself to the "
        f"group that owns it (usually dialout): sudo usermod -aG dialout {getpass.getuser()}, then log "
        "out and in again"
    )


def _launch_simavr(motor=None):
    if sys.platform == "win32":
        raise UnknownPortError(
            "port 'simavr' (the firmware on a simulated Uno) needs Linux or macOS; on "
            "Windows use the virtual rig, connect(), or a real Uno on its COM port"
        )
    try:
        # through sys.modules (not the package attribute), so a stand-in launcher can be swapped in
        simavr = importlib.import_module("jerklab.rig.simavr")
    except ImportError as exc:
        raise UnknownPortError(
            "port 'simavr' needs jerklab.rig.simavr (the firmware-on-simavr harness) which is not "
            f"available: {exc}"
        ) from exc
    kwargs = {}
    if motor is not None:
        if motor.supply_voltage is None or motor.encoder_ppr is None or motor.decoding != 1:
            raise ValueError(
                "motor for 'simavr' needs a supply_voltage, an encoder_ppr and decoding=1"
            )
        kwargs = dict(
            K=motor.K,
            tau=motor.tau,
            supply_voltage=motor.supply_voltage,
            coulomb_friction=motor.coulomb_friction,
            encoder_ppr=motor.encoder_ppr,
        )
        if getattr(motor, "n_states", 2) == 4:  # FlexibleDCMotor: the two-mass load
            kwargs.update(
                load_ratio=motor.load_ratio,
                mode_frequency=motor.mode_frequency,
                mode_damping=motor.mode_damping,
            )
    try:
        return simavr.launch(**kwargs)
    except FileNotFoundError as exc:
        raise UnknownPortError(
            f"port 'simavr': a tool or the firmware build is missing ({exc}); install simavr, "
            "libsimavr-dev, gcc-avr, avr-libc, arduino-core-avr and run `make -C firmware`"
        ) from exc
    except (RuntimeError, OSError) as exc:
        raise UnknownPortError(f"port 'simavr': the simulated Uno did not start: {exc}") from exc
