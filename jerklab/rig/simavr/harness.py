"""The simavr harness launcher: the rig firmware on a simulated Uno with a DC motor on its pins.

The harness (``firmware/simavr/jl_simavr.c``, built by ``make -C firmware simavr``) runs the
ELF on a cycle-accurate ATmega328P, bridges UART0 to a pseudo-terminal, reads the PWM duty
(OCR1A) and the L298 direction pins, integrates a DC motor (Stojčić eq. 1; ASCII: Stojcic) and
feeds quadrature edges back on INT0/INT1, so :func:`jerklab.rig.connect` talks to the actual
firmware over pyserial exactly as to a board on a USB port.

:func:`launch` returns once the firmware has switched its UART receiver on; bytes a host writes
earlier wait in the harness's bridge (as in the Uno's USB-serial chip) instead of being lost.
"""

from __future__ import annotations

import json
import math
import os
import selectors
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from jerklab import paper
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real
from jerklab.rig.simavr.build import build_firmware, default_build_dir

__all__ = ["launch", "SimulatedUno", "HarnessError", "tools_missing"]

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
    ready_seconds : float or None
        Simulated time (s) at which the firmware switched its UART receiver on (None if
        :func:`launch` did not wait for it).
    """

    def __init__(self, proc, port, workdir, params):
        self._proc = proc
        self.port = port
        self.pid = proc.pid
        self.params = params
        self._workdir = workdir
        self._stats_path = os.path.join(workdir.name, "stats.json")
        self.final_stats = None
        self.ready_seconds = None

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
            raise HarnessError(
                f"the simavr harness (pid {self.pid}) is not running (exit status "
                f"{self._proc.returncode}){self._log_tail()}"
            )
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
        raise HarnessError(
            f"the simavr harness (pid {self.pid}, state {state}, exit status "
            f"{self._proc.poll()}) wrote no stats in {timeout} s{self._log_tail()}"
        )

    def trace(self):
        """The harness's 1 ms trace so far (``launch(trace=True)``): an array of rows
        ``(t s, theta_motor rad, theta_load rad, volts V)`` in simulated time — the load's
        motion, which the encoder does not see. Read it before :meth:`close`."""
        import numpy as np

        path = os.path.join(self._workdir.name, "trace.txt") if self._workdir is not None else None
        if path is None or not os.path.exists(path):
            raise HarnessError(
                "no trace: launch the harness with trace=True (and read it before close())"
            )
        self.stats()  # the harness flushes its trace then
        rows = []
        with open(path) as fh:
            for line in fh:
                parts = line.split()
                if len(parts) == 4 and line.endswith("\n"):
                    rows.append([float(p) for p in parts])
        return np.array(rows).reshape(-1, 4)

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


def launch(
    elf=None,
    *,
    K=paper.MOTOR_K,
    tau=paper.MOTOR_TAU,
    supply_voltage=paper.SUPPLY_VOLTAGE,
    coulomb_friction=0.0,
    load_disturbance=0.0,
    encoder_ppr=paper.ENCODER_PPR,
    step_us=20,
    realtime=True,
    build=True,
    startup_timeout=20.0,
    bootloader=None,
    wait_ready=True,
    load_ratio=0.0,
    mode_frequency=2 * math.pi * 8.0,
    mode_damping=0.02,
    trace=False,
) -> SimulatedUno:
    """Start the firmware on a simulated Uno with a DC motor; return a :class:`SimulatedUno`.

    Returns once the firmware has switched its UART receiver on (``wait_ready``), so a host
    may write at once; bytes written even earlier wait in the harness, as in the Uno's
    USB-serial chip.

    Parameters
    ----------
    elf : path or False, optional
        Firmware ELF (default: ``firmware/build/jerklab_rig.elf``, built with
        ``make -C firmware`` when ``build`` is true). ``False`` (with ``bootloader``): an
        empty application flash, as on a board that has only its bootloader.
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
        Seconds to wait for the harness to print its pty and for the firmware's UART.
    bootloader : path or True, optional
        An Intel-hex bootloader loaded at its address (Optiboot: 0x7E00) and started first, as
        after the reset that opening the port causes on an Uno (MCUSR = EXTRF: Optiboot waits
        about 1 s for avrdude, then starts the application). ``True``: Optiboot built from
        arduino-core-avr's source by ``make -C firmware optiboot`` (Debian's prebuilt hex is
        532 bytes and does not fit the boot section: see firmware/README.md).
    wait_ready : bool
        Return only once the firmware's UART receiver is on (default). False returns as soon
        as the pty exists.
    load_ratio, mode_frequency, mode_damping : float
        A flexible load (``load_ratio > 0``): the two-mass model of
        :class:`jerklab.plant.FlexibleDCMotor` (J_l/J_m, the shaft's mode in rad/s, its damping
        ratio), the encoder on the motor; no Coulomb friction then. 0: the rigid motor.
    trace : bool
        Record the motor's and the load's angles and the bridge voltage every 1 ms of simulated
        time (:meth:`SimulatedUno.trace`).

    Raises
    ------
    FileNotFoundError
        simavr, the AVR toolchain or the Arduino core is missing (the message lists the
        Debian packages), or the ELF or bootloader does not exist.
    HarnessError
        The harness did not start, or the firmware never switched its UART receiver on.
    """
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    load_ratio = as_nonnegative("load_ratio", load_ratio)
    mode_frequency = as_positive("mode_frequency", mode_frequency)
    mode_damping = as_nonnegative("mode_damping", mode_damping)
    if load_ratio > 0 and coulomb_friction:
        raise ValueError(
            "coulomb_friction must be 0 with a flexible load (load_ratio > 0): the two-mass "
            "model has none"
        )
    supply_voltage = as_positive("supply_voltage", supply_voltage)
    coulomb_friction = as_nonnegative("coulomb_friction", coulomb_friction)
    load_disturbance = as_real("load_disturbance", load_disturbance)
    encoder_ppr = as_int("encoder_ppr", encoder_ppr, minimum=1)
    step_us = as_int("step_us", step_us, minimum=1)
    if step_us > 1000:
        raise ValueError(f"step_us must be <= 1000, got {step_us}")
    startup_timeout = as_positive("startup_timeout", startup_timeout)
    if (
        bootloader is not None
        and bootloader is not True
        and not isinstance(bootloader, (str, os.PathLike))
    ):
        raise TypeError(
            f"bootloader must be a path to an Intel-hex file or True, got {bootloader!r}"
        )
    if elf is False and bootloader is None:
        raise ValueError("elf=False (no application) needs a bootloader")
    missing = tools_missing()
    if missing:
        raise FileNotFoundError(
            f"the simulated Uno needs {', '.join(missing)} (Debian: apt-get install gcc-avr avr-libc "
            "arduino-core-avr simavr libsimavr-dev)"
        )
    if build:
        paths = build_firmware("avr", "simavr", *(("optiboot",) if bootloader is True else ()))
    else:
        build_dir = default_build_dir()
        paths = {
            "harness": build_dir / "jl_simavr",
            "elf": build_dir / "jerklab_rig.elf",
            "optiboot": build_dir / "optiboot_atmega328.hex",
        }
    harness = paths["harness"]
    elf = paths["elf"] if elf is None else elf
    if bootloader is True:
        bootloader = paths["optiboot"]
    checks = [("simavr harness", harness)]
    if elf is not False:
        elf = Path(elf)
        checks.append(("firmware ELF", elf))
    if bootloader is not None:
        bootloader = Path(bootloader)
        checks.append(("bootloader hex", bootloader))
    for what, path in checks:
        if not Path(path).is_file():
            hint = (
                "apt-get install arduino-core-avr"
                if what == "bootloader hex"
                else "run `make -C firmware`"
            )
            raise FileNotFoundError(f"{what} not found at {path} ({hint})")
    params = dict(
        K=K,
        tau=tau,
        supply_voltage=supply_voltage,
        coulomb_friction=coulomb_friction,
        load_disturbance=load_disturbance,
        encoder_ppr=encoder_ppr,
        step_us=step_us,
        realtime=bool(realtime),
        elf=None if elf is False else str(elf),
        bootloader=None if bootloader is None else str(bootloader),
        load_ratio=load_ratio,
        mode_frequency=mode_frequency,
        mode_damping=mode_damping,
    )
    workdir = tempfile.TemporaryDirectory(prefix="jerklab-simavr-")
    cmd = [
        str(harness),
        "--K",
        repr(K),
        "--tau",
        repr(tau),
        "--supply",
        repr(supply_voltage),
        "--friction",
        repr(coulomb_friction),
        "--load",
        repr(load_disturbance),
        "--ppr",
        str(encoder_ppr),
        "--step-us",
        str(step_us),
        "--stats",
        os.path.join(workdir.name, "stats.json"),
    ]
    addr = _symbol_address(elf, "g_counts") if elf is not False else None
    if addr is not None:
        cmd += ["--counts-addr", hex(addr)]
    if bootloader is not None:
        cmd += ["--bootloader", str(bootloader)]
    if not realtime:
        cmd.append("--fast")
    if load_ratio > 0:
        cmd += [
            "--load-ratio",
            repr(load_ratio),
            "--mode-hz",
            repr(mode_frequency / (2 * math.pi)),
            "--mode-zeta",
            repr(mode_damping),
        ]
    if trace:
        cmd += ["--trace", os.path.join(workdir.name, "trace.txt")]
    cmd.append("--no-app" if elf is False else str(elf))
    log = open(os.path.join(workdir.name, "harness.log"), "w")
    try:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=log, stdin=subprocess.DEVNULL, cwd=workdir.name
        )
    finally:
        log.close()
    port, ready = None, None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    buf = b""
    end = time.monotonic() + startup_timeout
    try:
        while (port is None or (wait_ready and ready is None)) and time.monotonic() < end:
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
                elif line.startswith("READY "):
                    ready = float(line.split()[1])
    finally:
        sel.close()
        proc.stdout.close()
    uno = SimulatedUno(proc, port, workdir, params)
    uno.ready_seconds = ready
    if port is None or (wait_ready and ready is None):
        tail = uno._log_tail()
        running = uno.running
        uno.close()
        what = (
            "printed no pty"
            if port is None
            else "ran, but the firmware never switched its UART receiver on (RXEN0)"
            if running
            else "exited before the firmware switched its UART receiver on"
        )
        raise HarnessError(
            f"the simavr harness {what} within {startup_timeout} s "
            f"(output: {buf.decode(errors='replace')!r}){tail}"
        )
    return uno
