"""The real rig firmware on a simulated Uno: build helpers and the simavr harness launcher.

``make -C firmware`` builds the Uno firmware (``build/jerklab_rig.elf``), the host build of its
portable core (``build/jl_host``) and the simavr harness (``build/jl_simavr``). The harness runs
the ELF on a cycle-accurate ATmega328P, bridges UART0 to a pseudo-terminal, reads the PWM duty
(OCR1A) and the L298 direction pins, integrates a DC motor (Stojčić eq. 1) and feeds quadrature
edges back on INT0/INT1, so :func:`jerklab.rig.connect` talks to the actual firmware over
pyserial exactly as to a board on a USB port.
"""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
from contextlib import contextmanager
from pathlib import Path

__all__ = ["firmware_dir", "build_firmware", "FirmwareBuildError"]


class FirmwareBuildError(RuntimeError):
    """``make -C firmware`` failed (the message carries its output)."""


def firmware_dir() -> Path:
    """The ``firmware/`` folder of the source tree (``JERKLAB_FIRMWARE_DIR`` overrides it)."""
    env = os.environ.get("JERKLAB_FIRMWARE_DIR")
    path = Path(env) if env else Path(__file__).resolve().parents[2] / "firmware"
    if not (path / "Makefile").is_file():
        raise FileNotFoundError(
            f"firmware sources not found at {path} (set JERKLAB_FIRMWARE_DIR to the firmware/ folder "
            "of a jerklab checkout)")
    return path


@contextmanager
def _build_lock(build: Path):
    build.mkdir(parents=True, exist_ok=True)
    with open(build / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)       # parallel test workers share one build folder
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def build_firmware(*targets: str, build_dir=None) -> dict:
    """Run ``make -C firmware <targets>`` (serialised by a file lock) and return the paths.

    Parameters
    ----------
    targets : str
        Make targets (``"avr"``, ``"size"``, ``"host"``, ``"simavr"``); none = the default
        (everything the installed tools allow).
    build_dir : path-like, optional
        Output folder (default ``firmware/build``).

    Returns
    -------
    dict
        ``elf``, ``hex``, ``host``, ``harness`` paths and ``output`` (make's stdout, which
        holds the flash/RAM line printed by the ``size`` target).
    """
    if shutil.which("make") is None:
        raise FirmwareBuildError("make is not installed")
    fw = firmware_dir()
    build = Path(build_dir) if build_dir is not None else fw / "build"
    for t in targets:
        if not isinstance(t, str) or not t.replace("_", "").isalnum():
            raise ValueError(f"targets must be make target names, got {t!r}")
    with _build_lock(build):
        proc = subprocess.run(["make", "-s", "-C", str(fw), f"BUILD={build}", *targets],
                              capture_output=True, text=True)
    if proc.returncode != 0:
        raise FirmwareBuildError(f"make -C {fw} {' '.join(targets)} failed:\n{proc.stdout}\n{proc.stderr}")
    return {"elf": build / "jerklab_rig.elf", "hex": build / "jerklab_rig.hex",
            "host": build / "jl_host", "harness": build / "jl_simavr", "output": proc.stdout}


# --------------------------------------------------------------------------- the harness

import json  # noqa: E402
import selectors  # noqa: E402
import signal  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

from jerklab._validate import as_int, as_nonnegative, as_positive, as_real  # noqa: E402

__all__ += ["launch", "SimulatedUno", "HarnessError", "tools_missing"]

_ARDUINO_CORE = "/usr/share/arduino/hardware/arduino/avr/cores/arduino"
_SIMAVR_HEADER = "/usr/include/simavr/sim_avr.h"


class HarnessError(RuntimeError):
    """The simavr harness did not start or died."""


def tools_missing() -> list:
    """Names of the Debian tools the simulated Uno needs and this machine lacks (empty: all there)."""
    missing = [t for t in ("make", "cc", "avr-g++", "avr-size") if shutil.which(t) is None]
    if not os.path.isdir(_ARDUINO_CORE):
        missing.append("arduino-core-avr")
    if not os.path.isfile(_SIMAVR_HEADER):
        missing.append("libsimavr-dev")
    return missing


class SimulatedUno:
    """A running harness: the firmware on a simulated ATmega328P with a motor on its pins.

    Attributes
    ----------
    port : str
        The pseudo-terminal (``/dev/pts/N``) bridged to the Uno's UART0 (115200 baud).
    pid : int
        The harness process.
    params : dict
        Motor and harness parameters it was started with.
    """

    def __init__(self, proc, port, workdir, params):
        self._proc = proc
        self.port = port
        self.pid = proc.pid
        self.params = params
        self._workdir = workdir
        self._stats_path = os.path.join(workdir.name, "stats.json")
        self.final_stats = None

    def __repr__(self):
        state = "running" if self.running else "closed"
        return f"SimulatedUno(port={self.port!r}, pid={self.pid}, {state})"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def running(self) -> bool:
        return self._proc.poll() is None

    def _read_stats(self):
        try:
            with open(self._stats_path) as fh:
                return json.load(fh)
        except (OSError, ValueError):
            return None

    def stats(self, timeout=5.0) -> dict:
        """A fresh snapshot of the harness: simulated time, motor state, what a perfect encoder
        decoder counted (``ideal_counts_x1``/``_x4``), the control-step cycle budget
        (``control_step_cycles_moving``: min/mean/max cycles with PB5 high while the motor
        moves or is driven), the real-time factor."""
        timeout = as_positive("timeout", timeout)
        if not self.running:
            if self.final_stats is not None:
                return self.final_stats
            raise HarnessError(f"the simavr harness (pid {self.pid}) is not running (exit status "
                               f"{self._proc.returncode}){self._log_tail()}")
        old = self._read_stats()
        seq0 = old["seq"] if old else 0
        self._proc.send_signal(signal.SIGUSR1)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            s = self._read_stats()
            if s and s["seq"] > seq0:
                return s
            time.sleep(0.01)
        try:
            with open(f"/proc/{self.pid}/stat") as fh:
                state = fh.read().split(")")[-1].split()[0]
        except OSError:
            state = "?"
        raise HarnessError(f"the simavr harness (pid {self.pid}, state {state}, exit status "
                           f"{self._proc.poll()}) wrote no stats in {timeout} s{self._log_tail()}")

    def _log_tail(self, n=2000):
        try:
            with open(os.path.join(self._workdir.name, "harness.log")) as fh:
                text = fh.read()[-n:]
        except OSError:
            return ""
        return f"; its log ends:\n{text}" if text else ""

    def close(self):
        """End the harness (SIGTERM; it writes its final stats and exits) and clean up."""
        if self._workdir is None:
            return
        if self._proc.poll() is None:
            self._proc.send_signal(signal.SIGTERM)
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=5)
        self.final_stats = self._read_stats()
        self._workdir.cleanup()
        self._workdir = None


def _symbol_address(elf, name):
    """Data-space address of a variable of the ELF (avr-nm), or None."""
    nm = shutil.which("avr-nm")
    if nm is None:
        return None
    out = subprocess.run([nm, "-C", str(elf)], capture_output=True, text=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name and parts[1] in "bBdD":
            return int(parts[0], 16) - 0x800000
    return None


def launch(elf=None, *, K=32.4, tau=0.025, supply_voltage=12.0, coulomb_friction=0.0,
           load_disturbance=0.0, encoder_ppr=448, step_us=20, realtime=True, build=True,
           startup_timeout=20.0) -> SimulatedUno:
    """Start the firmware on a simulated Uno with a DC motor; return a :class:`SimulatedUno`.

    Parameters
    ----------
    elf : path, optional
        Firmware ELF (default: ``firmware/build/jerklab_rig.elf``, built with
        ``make -C firmware`` when ``build`` is true).
    K, tau : float
        Motor gain rad/(V s) and time constant s (Stojčić eq. 1; paper: 32.4, 0.025).
    supply_voltage : float
        H-bridge supply (V): full PWM duty.
    coulomb_friction, load_disturbance : float
        Equivalent voltages (V), as in :class:`jerklab.plant.DCMotor`.
    encoder_ppr : int
        Pulses per revolution of one encoder channel (448).
    step_us : int
        Motor integration step (µs of simulated time); encoder edges inside a step are placed
        at their interpolated times.
    realtime : bool
        Pace the simulation to the wall clock like a real board (default). False runs as fast
        as the host allows — the firmware's host watchdog then sees the host's heartbeats
        sped down, so use a generous ``host_timeout``.
    build : bool
        Run ``make -C firmware avr simavr`` first (incremental).
    startup_timeout : float
        Seconds to wait for the harness to print its pty.

    Raises
    ------
    FileNotFoundError
        simavr, the AVR toolchain or the Arduino core is missing (the message lists the
        Debian packages), or the ELF does not exist.
    HarnessError
        The harness did not start.
    """
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    supply_voltage = as_positive("supply_voltage", supply_voltage)
    coulomb_friction = as_nonnegative("coulomb_friction", coulomb_friction)
    load_disturbance = as_real("load_disturbance", load_disturbance)
    encoder_ppr = as_int("encoder_ppr", encoder_ppr, minimum=1)
    step_us = as_int("step_us", step_us, minimum=1)
    if step_us > 1000:
        raise ValueError(f"step_us must be <= 1000, got {step_us}")
    startup_timeout = as_positive("startup_timeout", startup_timeout)
    missing = tools_missing()
    if missing:
        raise FileNotFoundError(
            f"the simulated Uno needs {', '.join(missing)} (Debian: apt-get install gcc-avr avr-libc "
            "arduino-core-avr simavr libsimavr-dev)")
    if build:
        paths = build_firmware("avr", "simavr")
        harness = paths["harness"]
        elf = paths["elf"] if elf is None else Path(elf)
    else:
        build_dir = firmware_dir() / "build"
        harness = build_dir / "jl_simavr"
        elf = build_dir / "jerklab_rig.elf" if elf is None else Path(elf)
    for what, path in (("firmware ELF", elf), ("simavr harness", harness)):
        if not Path(path).is_file():
            raise FileNotFoundError(f"{what} not found at {path} (run `make -C firmware`)")
    params = dict(K=K, tau=tau, supply_voltage=supply_voltage, coulomb_friction=coulomb_friction,
                  load_disturbance=load_disturbance, encoder_ppr=encoder_ppr, step_us=step_us,
                  realtime=bool(realtime), elf=str(elf))
    workdir = tempfile.TemporaryDirectory(prefix="jerklab-simavr-")
    cmd = [str(harness), "--K", repr(K), "--tau", repr(tau), "--supply", repr(supply_voltage),
           "--friction", repr(coulomb_friction), "--load", repr(load_disturbance),
           "--ppr", str(encoder_ppr), "--step-us", str(step_us),
           "--stats", os.path.join(workdir.name, "stats.json")]
    addr = _symbol_address(elf, "g_counts")
    if addr is not None:
        cmd += ["--counts-addr", hex(addr)]
    if not realtime:
        cmd.append("--fast")
    cmd.append(str(elf))
    log = open(os.path.join(workdir.name, "harness.log"), "w")
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, stdin=subprocess.DEVNULL,
                                cwd=workdir.name)
    finally:
        log.close()
    port = None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    buf = b""
    end = time.monotonic() + startup_timeout
    try:
        while port is None and time.monotonic() < end:
            if not sel.select(timeout=0.1):
                if proc.poll() is not None:
                    break
                continue
            chunk = os.read(proc.stdout.fileno(), 4096)
            if not chunk:
                break
            buf += chunk
            for line in buf.decode(errors="replace").splitlines():
                if line.startswith("PTY /"):
                    port = line[4:].strip()
    finally:
        sel.close()
        proc.stdout.close()
    uno = SimulatedUno(proc, port, workdir, params)
    if port is None:
        tail = uno._log_tail()
        uno.close()
        raise HarnessError(f"the simavr harness printed no pty within {startup_timeout} s "
                           f"(output: {buf.decode(errors='replace')!r}){tail}")
    return uno
