"""Host-in-the-loop latency on the virtual rig in process (issue 30, part 3; the TCP port and
the simulated Uno are not measured yet).

Round trip per tick = HOST_SAMPLE sent by the device to the matching HOST_VOLTAGE received by
it, on the device's clock (``time.monotonic``, shared in process): the host's decoding, its
Python P law and its encoding. The device's deadline is Ts after the sample
(firmware/PROTOCOL.md "Host-in-the-loop"), so the run is not paced: the virtual device ticks as
soon as the host reads, and a miss means a round trip longer than Ts. The smallest Ts of the
mode's grid (5, 10, 20, 50 ms) at which 1,000 ticks pass without a miss is printed with them.
"""

from __future__ import annotations

import math
import tempfile

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


def _run(Ts, n_ticks, folder):
    dev = _TimedDevice()
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
    return np.asarray(dev.round_trips), int(rec.metadata["misses"]), rec.metadata["status"]


def main(n_ticks=1000):
    rows = []
    smallest = None
    with tempfile.TemporaryDirectory() as folder:
        for Ts in (0.005, 0.010, 0.020, 0.050):
            rt, misses, status = _run(Ts, n_ticks, folder)
            p50, p99, mx = (1e3 * float(x) for x in np.percentile(rt, [50, 99, 100]))
            rows.append((f"{Ts * 1e3:g} ms", len(rt), p50, p99, mx, misses, status))
            if misses == 0 and status == "complete" and smallest is None:
                smallest = Ts
    record_table(
        f"Host-in-the-loop round trip per tick, virtual rig in process ({n_ticks} ticks, P law)",
        ["Ts", "answers", "p50 ms", "p99 ms", "max ms", "misses", "status"],
        rows,
        note=(
            f"smallest Ts without a miss in {n_ticks} ticks: "
            + (f"{smallest * 1e3:g} ms" if smallest is not None else "none of 5-50 ms")
        ),
    )


if __name__ == "__main__":
    main()
