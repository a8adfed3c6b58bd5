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

The options come in three groups (:mod:`jerklab.rig.options`): ``connect(port,
device=Device(motor, speed=...), link=Link(timeout=...))`` and ``rig.run_move(profile, gains,
spec=RunSpec(settle=0.4))`` (or ``run_move(profile, gains, Ts, settle=0.4)``, the RunSpec fields
as keywords). The rig runs a device; who runs it is the caller's business (``connect(...,
metadata={...})`` puts the caller's fields into every recording).

``python -m jerklab.rig serve`` puts the virtual rig on a pseudo-terminal so any serial
client can talk to it as to a board.
"""

from __future__ import annotations

import getpass
import importlib
import os
import re
import socket
import sys

from jerklab import paper
from jerklab.plant import DCMotor, FlexibleDCMotor
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
from jerklab.rig.options import BAUDRATE, MIN_TIMEOUT, Device, Link, RunSpec
from jerklab.rig.ports import PortLock, port_holders
from jerklab.rig.ports import list_ports as _list_ports
from jerklab.rig.profiles import MotorProfile, load_profile, profile_names
from jerklab.rig.recording import Recording, compare, plot_comparison, recordings_dir
from jerklab.rig.virtual import VirtualDevice, VirtualSerial

__all__ = [
    "connect",
    "Rig",
    "Link",
    "Device",
    "RunSpec",
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
    "MotorProfile",
    "load_profile",
    "profile_names",
    "BAUDRATE",
    "MIN_TIMEOUT",
]

_VIRTUAL_NAMES = (None, "virtual")
_URL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "alt", "hwgrep", "cp2110")

#: keywords connect() took before its options were grouped -> what to write now (``motor=``
#: stays the older name of ``device=`` given a motor, as the vocabulary keeps older names)
_REGROUPED = {
    "plant": "device=FlexibleDCMotor() for the flexible load (jerklab.plant)",
    "speed": "device=Device(motor, speed=...)",
    "supply_voltage": "device=Device(supply_voltage=...)",
    "counts_per_rev": "device=Device(counts_per_rev=...)",
    "timeout": "link=Link(timeout=...)",
    "hello_timeout": "link=Link(hello_timeout=...)",
    "baudrate": "link=Link(baudrate=...)",
}


def list_ports(include_all=False) -> list:
    """Serial ports that may have a rig behind them, likely Arduinos first
    (see :func:`jerklab.rig.ports.list_ports`; ``python -m jerklab.rig ports`` prints them)."""
    return _list_ports(include_all=include_all)


def connect(
    port=None,
    *,
    device=None,
    link=None,
    model=None,
    profile=None,
    progress=True,
    recordings=None,
    metadata=None,
    live=None,
    **regrouped,
) -> Rig:
    """Connect to a rig and return a :class:`Rig`.

    Parameters
    ----------
    port : None, str or path
        ``None`` (or ``"virtual"``): the in-process virtual rig (``VirtualDevice`` driving the
        device's motor). ``"simavr"``: the firmware ELF on a simulated Uno
        (``jerklab.rig.simavr.launch()``). Anything else: a device path (``/dev/ttyACM0``,
        ``COM3``, a ``/dev/pts/N`` from ``python -m jerklab.rig serve``) or a pyserial URL
        (``socket://host:port``, ``loop://``, ``rfc2217://...``).
    device : Device or jerklab.plant motor, optional
        The hardware (:class:`jerklab.rig.Device`): for the virtual rig and ``"simavr"`` the
        simulated motor (default the paper's, K = 32.4 rad/(V s), tau = 25 ms; a
        ``jerklab.plant.FlexibleDCMotor`` gives a flexible load), the virtual rig's speed and
        encoder count noise; for any rig its supply and counts per revolution (default the
        motor's, else 12 V and 448). A bare motor is short for ``Device(motor)``.
    link : Link, optional
        Timeouts, baud rate and pyserial options (:class:`jerklab.rig.Link`).
    model : (K, tau), optional
        Motor model for the feedforward until you call ``rig.set_model`` (default the
        profile's K and τ, else the paper's values).
    profile : str, path or MotorProfile, optional
        The rig's motor (:mod:`jerklab.rig.profiles`): a built-in name (``"pololu-37d-30"``),
        a profile file written by ``jerklab rig check --save``, or a profile. It gives the
        supply, the counts per revolution and the model where ``device`` and ``model`` do not,
        and the virtual rig's motor (the profile's nominal motor) when ``device`` has none (a
        simulated motor given in ``device`` keeps its own encoder and supply).
        The rig keeps it as ``rig.profile`` (None when not given).
    progress : bool
        Progress bar during runs: an ipywidgets bar inside a Jupyter kernel, text in a terminal,
        nothing when False.
    recordings : path
        Folder for recordings (default ``$JERKLAB_RECORDINGS`` or ``./recordings``).
    live : bool or None
        Live plot of the runs in a Jupyter kernel (:mod:`jerklab.rig.live`): None (default:
        on unless ``$JERKLAB_LIVE_PLOT=0``), True or False; a run's ``live=`` overrides it.
    metadata : dict, optional
        The caller's fields, carried in every recording's metadata under ``"caller"``.
    motor : jerklab.plant motor, optional
        The older name of ``device`` given a bare motor (``connect(motor=m)`` is
        ``connect(device=m)``).

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
        A simulated-only device field (motor, speed, count noise) for a real port; a bad
        field of ``link`` or ``device`` (:class:`Link`, :class:`Device` name it).
    TypeError
        A keyword connect() no longer takes: the message says where it went.
    """
    if "motor" in regrouped:
        motor = regrouped.pop("motor")
        if device is not None:
            raise TypeError("give the simulated motor once: device= (motor= is its older name)")
        device = motor
    if regrouped:
        raise TypeError(_regrouped_message(regrouped))
    link = _as_link(link)
    device = _as_device(device)
    prof = None if profile is None else load_profile(profile)
    if model is None:
        model = (paper.MOTOR_K, paper.MOTOR_TAU) if prof is None else (prof.K, prof.tau)
    if prof is not None and device.motor is None:
        # a simulated rig runs the profile's nominal motor (its encoder and supply with it); a
        # real board takes the profile's supply and counts; a given motor keeps its own
        if port in _VIRTUAL_NAMES or port == "simavr":
            device = device.replace(motor=prof.motor())
        else:
            device = device.replace(
                supply_voltage=_or(device.supply_voltage, prof.supply_voltage),
                counts_per_rev=_or(device.counts_per_rev, prof.counts_per_rev),
            )
    if live is not None and not isinstance(live, bool):
        raise TypeError(f"live must be True, False or None, got {live!r}")
    rig = _connect(port, device, link, model, progress, recordings, metadata)
    rig.profile = prof
    rig.live = live
    return rig


def _connect(port, device, link, model, progress, recordings, metadata) -> Rig:
    if port in _VIRTUAL_NAMES:
        motor = DCMotor() if device.motor is None else device.motor
        dev = VirtualDevice(motor, count_noise=device.count_noise, noise_seed=device.noise_seed)
        return Rig(
            VirtualSerial(dev, speed=device.speed, timeout=0.05),
            "virtual",
            supply_voltage=_or(device.supply_voltage, motor.supply_voltage),
            counts_per_rev=_or(device.counts_per_rev, motor.encoder_ppr * motor.decoding),
            model=model,
            timeout=link.timeout,
            hello_timeout=_or(link.hello_timeout, 1.0),
            progress=progress,
            recordings=recordings,
            metadata=metadata,
        )
    if port != "simavr" and device.simulated_only:
        raise ValueError(
            f"device.{device.simulated_only[0]} applies to a simulated rig (port=None or "
            f"'simavr'), not to the board at {port!r}: a real board has its own motor"
        )
    port = _check_port(port)
    supply, cpr = device.supply_voltage, device.counts_per_rev
    on_close = None
    if port == "simavr":
        extra = [n for n in device.simulated_only if n != "motor"]
        if extra:
            raise ValueError(
                f"device.{extra[0]} applies to the virtual rig only (port=None), not 'simavr'"
            )
        launcher = _launch_simavr(device.motor)
        port, on_close = launcher.port, launcher.close
        if device.motor is not None:
            supply = _or(supply, device.motor.supply_voltage)
            cpr = _or(cpr, device.motor.encoder_ppr * device.motor.decoding)
    lock = None
    try:
        if "://" not in port:
            lock = PortLock(port).acquire()
        serial_link = _open_serial(port, link)
    except BaseException:
        if lock is not None:
            lock.release()
        if on_close is not None:
            on_close()
        raise
    if lock is not None:
        on_close = _chain(lock.release, on_close)
    return Rig(
        serial_link,
        port,
        supply_voltage=_or(supply, paper.SUPPLY_VOLTAGE),
        counts_per_rev=_or(cpr, paper.ENCODER_PPR * paper.ENCODER_DECODING),
        model=model,
        timeout=link.timeout,
        hello_timeout=_or(link.hello_timeout, 3.0),
        progress=progress,
        recordings=recordings,
        on_close=on_close,
        metadata=metadata,
    )


def _or(value, default):
    return default if value is None else value


def _as_link(link) -> Link:
    if link is None:
        return Link()
    if not isinstance(link, Link):
        raise TypeError(f"link must be a jerklab.rig.Link, got {type(link).__name__}")
    return link


def _as_device(device) -> Device:
    if device is None:
        return Device()
    if isinstance(device, Device):
        return device
    if isinstance(device, (DCMotor, FlexibleDCMotor)):
        return Device(device)
    raise TypeError(
        f"device must be a jerklab.rig.Device or a jerklab.plant motor, got {type(device).__name__}"
    )


def _regrouped_message(kwargs) -> str:
    name = sorted(kwargs)[0]
    if name == "student":
        return (
            "connect() takes no student: a rig runs a device and knows nobody. For a student's "
            "hidden motor use jerklab.lab.connect_student(student, port) or jerklab.lab.start(lab, "
            "student, port)"
        )
    if name in _REGROUPED:
        return f"connect() takes {name} no longer as a keyword: write {_REGROUPED[name]}"
    return f"connect() got an unexpected keyword argument {name!r}"


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
    return (
        sys.platform.startswith("win")
        and re.fullmatch(r"(\\\\\.\\)?COM\d+", port, re.I) is not None
    )


def _open_serial(port, link: Link):
    import serial  # pyserial, for a port only

    kwargs = dict(baudrate=link.baudrate, timeout=0.05, write_timeout=2.0)
    if "://" not in port and os.name == "posix":
        kwargs["exclusive"] = True  # TIOCEXCL + flock: a second open fails
    kwargs.update(link.serial_options)
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
            who = (
                "; ".join(f"pid {pid} ({cmd})" for pid, cmd in port_holders(port))
                or "another program"
            )
            raise PortBusyError(f"port {port!r} is in use by {who}: {exc}", port=port) from exc
        raise UnknownPortError(f"cannot open rig port {port!r}: {exc}") from exc
    _no_delay(link)
    try:
        link.reset_input_buffer()
    except Exception:
        pass
    return link


def _no_delay(link):
    """Send each frame at once on a ``socket://`` link (``TCP_NODELAY``).

    pyserial's socket handler leaves Nagle's algorithm on: a frame written while the previous
    one is unacknowledged waits for the peer's delayed ACK (40 ms on Linux), which made the host
    loop's round trip on a TCP port 37 ms at the median (``python -m benchmarks hostloop``) and
    missed every deadline below 50 ms.
    """
    sock = getattr(link, "_socket", None)
    if isinstance(sock, socket.socket) and sock.family in (socket.AF_INET, socket.AF_INET6):
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass


def _permission_message(port, exc):
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
