"""Host-in-the-loop latency on the virtual rig in process and on a TCP port, and on the firmware on
a simulated Uno at 115200 baud and at 1 Mbaud (issue 30, part 3).

Round trip per tick = HOST_SAMPLE sent by the device to the matching HOST_VOLTAGE received by
it, on the device's clock (``time.monotonic``, shared in process): the host's decoding, its
Python P law and its encoding. The device's deadline is Ts after the sample
(firmware/PROTOCOL.md "Host-in-the-loop"), so the run is not paced: the virtual device ticks as
soon as the host reads, and a miss means a round trip longer than Ts. The smallest Ts of the
mode's grid (5, 10, 20, 50 ms) at which 1,000 ticks pass without a miss is printed with them.

On the TCP port the same device is served by ``DeviceServer.start_tcp`` on 127.0.0.1 (what
``python -m jerklab.rig serve --tcp`` runs, unpaced) and the host connects to its
``socket://`` URL: the round trip adds both ways through the loopback socket and the serving
thread, still on the device's clock.

On the simulated Uno (``connect("simavr")``, the sketch built for the baud rate with ``JL_BAUD``,
paced to the wall clock) the device's clock is not the host's: the round trip is the host's
turnaround (HOST_SAMPLE received to HOST_VOLTAGE written, from the recording's deadline slack:
Ts - slack) plus the line time of the two frames at the baud rate (21 + 20 bytes of 10 bits),
and the misses are the firmware's own count (HOST_SAMPLE flag bit 0). That round trip is a
lower bound: the pseudo-terminal's and the harness's latency, both ways, are not seen from the
host (misses at a Ts above it are those). The grid is tried from
5 ms up and stops at the first Ts with 1,000 ticks without a miss (the longer ones would take
up to 50 s each). A loaded machine adds misses: the harness's forgiven lag (the simulation's
clock falling behind the wall clock) is printed with each row.
"""

from __future__ import annotations

import math
import tempfile
import time

import numpy as np

from benchmarks._record import table as record_table
from jerklab.rig.client import Rig
from jerklab.rig.virtual import VirtualDevice, VirtualSerial


class _TimedDevice(VirtualDevice):
    """A virtual device that keeps the round trip of every HOST_VOLTAGE it receives."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.round_trips = []

    def _host_voltage(self, frame, m):
        if self._hl_sent_at is not None:
            self.round_trips.append(self.clock() - self._hl_sent_at)
        return super()._host_voltage(frame, m)


def _run(Ts, n_ticks, folder, tcp=False):
    dev = _TimedDevice()
    server = None
    if tcp:
        from jerklab.rig import connect
        from jerklab.rig.server import DeviceServer

        server = DeviceServer(dev, speed=1.0)
        rig = connect(server.start_tcp("127.0.0.1", 0), recordings=folder, progress=False)
    else:
        rig = Rig(VirtualSerial(dev), port="virtual", recordings=folder, progress=False)
    try:
        rec = rig.host_loop(
            lambda t, y, r: 0.3 * (r - y),  # V/rad: stable with the one-tick delay up to 50 ms
            Ts=Ts,
            duration=(n_ticks - 1) * Ts,
            reference=math.pi,
            max_misses=255,
            max_error=0.0,
        )
    finally:
        rig.close()
        if server is not None:
            server.close()
    return np.asarray(dev.round_trips), int(rec.metadata["misses"]), rec.metadata["status"]


#: bytes on the line per tick: a HOST_SAMPLE frame (7 + 14) and a HOST_VOLTAGE frame (7 + 13)
_LINE_BYTES = 21 + 20


def _run_uno(sim, baud, Ts, n_ticks, folder):
    from jerklab.rig import Link, connect

    lag0 = sim.stats()["lag_forgiven_seconds"]
    with connect(
        sim.port, recordings=folder, progress=False, link=Link(timeout=10.0, baudrate=baud)
    ) as rig:
        rec = rig.host_loop(
            lambda t, y, r: 0.3 * (r - y),
            Ts=Ts,
            duration=(n_ticks - 1) * Ts,
            reference=math.pi,
            max_misses=255,
            max_error=0.0,
        )
    slack = np.asarray(rec.metadata["hostloop"]["slack"], dtype=float)
    rt = (Ts - slack) + _LINE_BYTES * 10.0 / baud
    lag = sim.stats()["lag_forgiven_seconds"] - lag0
    return rt, int(rec.metadata["misses"]), rec.metadata["status"], lag


def uno_rows(n_ticks=1000):
    """The simulated Uno at 115200 baud and 1 Mbaud: rows up to the smallest Ts without a miss,
    and that Ts per baud rate (None: none of the grid)."""
    from jerklab.rig import simavr

    missing = simavr.tools_missing()
    if missing:
        print(f"simulated Uno skipped: needs {', '.join(missing)}")
        return [], {}
    fw = simavr.firmware_dir()
    simavr.build_firmware("simavr")
    rows, smallest = [], {}
    with tempfile.TemporaryDirectory() as folder:
        for baud in (115200, 1000000):
            elf = simavr.build_firmware(
                "avr", build_dir=fw / "build" / f"hostloop{baud}", baud=baud
            )["elf"]
            smallest[baud] = None
            with simavr.launch(elf, build=False) as sim:
                for Ts in (0.005, 0.010, 0.020, 0.050):
                    t0 = time.monotonic()
                    rt, misses, status, lag = _run_uno(sim, baud, Ts, n_ticks, folder)
                    p50, p99, mx = (1e3 * float(x) for x in np.percentile(rt, [50, 99, 100]))
                    rows.append(
                        (
                            f"{baud} baud, {Ts * 1e3:g} ms",
                            len(rt),
                            p50,
                            p99,
                            mx,
                            misses,
                            f"{lag * 1e3:.0f}",
                            f"{time.monotonic() - t0:.1f}",
                            status,
                        )
                    )
                    if misses == 0 and status == "complete":
                        smallest[baud] = Ts
                        break
    return rows, smallest


def main(n_ticks=1000):
    for tcp in (False, True):
        rows = []
        smallest = None
        with tempfile.TemporaryDirectory() as folder:
            for Ts in (0.005, 0.010, 0.020, 0.050):
                rt, misses, status = _run(Ts, n_ticks, folder, tcp=tcp)
                p50, p99, mx = (1e3 * float(x) for x in np.percentile(rt, [50, 99, 100]))
                rows.append((f"{Ts * 1e3:g} ms", len(rt), p50, p99, mx, misses, status))
                if misses == 0 and status == "complete" and smallest is None:
                    smallest = Ts
        where = "on a TCP port (127.0.0.1)" if tcp else "in process"
        record_table(
            f"Host-in-the-loop round trip per tick, virtual rig {where} ({n_ticks} ticks, P law)",
            ["Ts", "answers", "p50 ms", "p99 ms", "max ms", "misses", "status"],
            rows,
            note=(
                f"smallest Ts without a miss in {n_ticks} ticks: "
                + (f"{smallest * 1e3:g} ms" if smallest is not None else "none of 5-50 ms")
            ),
        )
    rows, small = uno_rows(n_ticks)
    if rows:
        record_table(
            f"Host-in-the-loop round trip per tick, firmware on the simulated Uno ({n_ticks} ticks, P law)",
            [
                "link, Ts",
                "answers",
                "p50 ms",
                "p99 ms",
                "max ms",
                "misses",
                "lag forgiven ms",
                "wall s",
                "status",
            ],
            rows,
            note="smallest Ts without a miss in "
            + f"{n_ticks} ticks: "
            + ", ".join(
                f"{b} baud {t * 1e3:g} ms" if t is not None else f"{b} baud none of 5-50 ms"
                for b, t in small.items()
            )
            + " (round trip = host turnaround + the two frames' line time: a lower bound, the"
            + " pty's and the harness's latency unseen)",
        )


if __name__ == "__main__":
    main()
