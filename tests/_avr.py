"""Run a small test program on the simulated ATmega328P: compile it with avr-g++ against the
firmware core's sources, run it in simavr, and return what it printed on the UART."""

from __future__ import annotations

import re
import subprocess


def run_on_atmega328p(
    tmp_path, source, core=("jl_fixed.cpp", "jl_control.cpp", "jl_asm_mac.cpp", "jl_asm_pid.cpp"), flags=()
):
    """Compile ``source`` (C++ text) with the core files ``core`` of firmware/jerklab_rig/src,
    run it in simavr and return its UART output as one string (simavr's colour codes and line
    breaks removed)."""
    from jerklab.rig.simavr.build import firmware_dir

    src = firmware_dir() / "jerklab_rig" / "src"
    (tmp_path / "t.cpp").write_text(source)
    elf = tmp_path / "t.elf"
    subprocess.run(
        [
            "avr-g++",
            "-mmcu=atmega328p",
            "-DF_CPU=16000000L",
            "-Os",
            "-std=gnu++11",
            f"-I{src}",
            str(tmp_path / "t.cpp"),
            *(str(src / f) for f in core),
            *flags,
            "-o",
            str(elf),
        ],
        check=True,
        capture_output=True,
        timeout=120,
    )
    run = subprocess.run(
        ["simavr", "-m", "atmega328p", "-f", "16000000", str(elf)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    # (simavr echoes the UART on stderr in colour, broken into lines)
    return re.sub(r"\x1b\[[0-9;]*m|[\r\n]", "", run.stderr + run.stdout)
