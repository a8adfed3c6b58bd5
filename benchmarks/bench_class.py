"""A class on one server: N simulated students against the class page (issue 14).

Each student is a websocket client doing what the page's JavaScript does, so the server sees
the same load as from N browsers while this machine's cores are not spent on N Chromiums:

1. ``GET /`` of ``python -m jerklab.app`` (Voilà renders ``app/tuning.ipynb``, from its pool of
   pre-executed kernels when there is one);
2. opens the kernel's websocket (``/api/kernels/<id>/channels``), opens the
   ``jupyter.widget.control`` comm and asks for the widget states (``request_states``) — the
   panel can be drawn once they have arrived: that instant is "panel shown";
3. every 2 s moves the ωn slider (a comm ``update`` of the slider's ``value``) and waits for the
   kernel's ``update`` of the figure's ``Image`` model: that delay is "slider → image".

The server is started with the documented command, on a free port, with its default options
plus ``--pool``; the clients arrive together (0–2 s jitter) once the pool is full (the page is
started before the lesson). Server memory is the resident set of the Voilà process and all its
kernels, sampled every 2 s. After the last tab closes the kernels still alive are counted after
``--after`` seconds (culling of idle kernels).

Run::

    python -m benchmarks class                       # N = 1, 10, 30, 3 minutes each
    python -m benchmarks class --minutes=0.5 --n=1,10
    python -m benchmarks.bench_class --n 30 --pool 30

Targets (issue 14): every panel within 5 s, slider → image p90 ≤ 1 s at N = 30.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import pathlib
import random
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ------------------------------------------------------------------------------ the server
class Server:
    """``python -m jerklab.app`` in its own process group, its log read by a thread."""

    def __init__(self, pool, extra=()):
        self.port = _free_port()
        env = dict(os.environ)
        env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "jerklab.app", f"--port={self.port}", f"--pool={pool}", *extra],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        self.pool = pool
        self.filled = threading.Event()
        self.log = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.log.append(line)
            m = re.search(r"pool of .* filled with (\d+) kernel", line)
            if m and int(m.group(1)) >= self.pool:
                self.filled.set()

    def wait_ready(self, timeout):
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if self.proc.poll() is not None:
                raise RuntimeError("class page exited:\n" + "".join(self.log[-30:]))
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    break
            except OSError:
                time.sleep(0.5)
        if self.pool and not self.filled.wait(max(1.0, timeout - (time.monotonic() - t0))):
            raise RuntimeError(f"pool of {self.pool} not filled in {timeout:.0f} s")
        # the pool's kernels have started; wait until they have run the page (CPU quiet)
        import psutil

        while time.monotonic() - t0 < timeout:
            procs = self.processes()
            for p in procs:
                try:
                    p.cpu_percent(None)
                except psutil.Error:
                    pass
            time.sleep(2.0)
            busy = 0.0
            for p in procs:
                try:
                    busy += p.cpu_percent(None)
                except psutil.Error:
                    pass
            if busy < 20.0:
                break
        return time.monotonic() - t0

    def processes(self):
        import psutil

        try:
            root = psutil.Process(self.proc.pid)
            return [root] + root.children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def rss(self):
        total = 0
        for p in self.processes():
            try:
                total += p.memory_info().rss
            except Exception:
                pass
        return total

    def kernels(self):
        n = 0
        for p in self.processes()[1:]:
            try:
                if "ipykernel" in " ".join(p.cmdline()):
                    n += 1
            except Exception:
                pass
        return n

    def stop(self):
        try:
            os.killpg(self.proc.pid, signal.SIGINT)
            self.proc.wait(15)
        except Exception:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


# ----------------------------------------------------------------------------- a student
WS_PROTOCOL = "v1.kernel.websocket.jupyter.org"


def _decode(frame):
    """A message in the v1 kernel websocket protocol (jupyter_server): offsets, channel, parts."""
    n = int.from_bytes(frame[:8], "little")
    off = [int.from_bytes(frame[8 * (i + 1) : 8 * (i + 2)], "little") for i in range(n)]
    parts = [frame[off[i] : off[i + 1]] for i in range(n - 1)]
    channel = parts[0].decode("utf-8")
    header, parent, metadata, content = (json.loads(p) for p in parts[1:5])
    return {
        "channel": channel,
        "header": header,
        "parent_header": parent,
        "metadata": metadata,
        "content": content,
        "buffers": parts[5:],
    }


def _msg(session, msg_type, content, channel="shell", metadata=None):
    """Encode a client message for the v1 protocol."""
    header = {
        "msg_id": uuid.uuid4().hex,
        "username": "student",
        "session": session,
        "msg_type": msg_type,
        "version": "5.3",
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    parts = [channel.encode()] + [
        json.dumps(x).encode() for x in (header, {}, metadata or {}, content)
    ]
    off = [8 * (1 + len(parts) + 1)]
    for p in parts:
        off.append(off[-1] + len(p))
    return (
        len(off).to_bytes(8, "little")
        + b"".join(o.to_bytes(8, "little") for o in off)
        + b"".join(parts)
    ), header["msg_id"]


class Student:
    def __init__(self, idx, base, stats, period=2.0, timeout=30.0):
        self.idx, self.base, self.stats = idx, base, stats
        self.period, self.timeout = period, timeout
        self.session = uuid.uuid4().hex

    async def run(self, duration, jitter):
        from tornado.httpclient import AsyncHTTPClient, HTTPRequest
        from tornado.websocket import websocket_connect

        await asyncio.sleep(jitter)
        t0 = time.monotonic()
        try:
            resp = await AsyncHTTPClient().fetch(HTTPRequest(self.base + "/", request_timeout=300))
            html = resp.body.decode("utf-8", "replace")
            kid = re.search(r'kernelId"\s*:\s*"([0-9a-f-]{36})"', html).group(1)
            t_html = time.monotonic() - t0
            ws = await websocket_connect(
                f"{self.base.replace('http', 'ws')}/api/kernels/{kid}/channels?session_id={self.session}",
                subprotocols=[WS_PROTOCOL],
            )
            # as the widget manager does: list the kernel's widget comms, ask each for its state
            await ws.write_message(
                _msg(self.session, "comm_info_request", {"target_name": "jupyter.widget"})[0],
                binary=True,
            )
            comms = None
            while comms is None:
                msg = _decode(await asyncio.wait_for(ws.read_message(), self.timeout * 4))
                if msg["header"]["msg_type"] == "comm_info_reply":
                    comms = list(msg["content"]["comms"])
            last = None
            for cid in comms:
                req, last = _msg(
                    self.session, "comm_msg", {"comm_id": cid, "data": {"method": "request_state"}}
                )
                await ws.write_message(req, binary=True)
            states = {}
            while True:  # replies come before the kernel's idle after the last request
                msg = _decode(await asyncio.wait_for(ws.read_message(), self.timeout * 4))
                c = msg.get("content", {})
                if (
                    msg["header"]["msg_type"] == "comm_msg"
                    and c.get("comm_id") in comms
                    and c["data"].get("method") == "update"
                ):
                    states[c["comm_id"]] = {
                        "model_name": c["data"]["state"].get("_model_name"),
                        "state": c["data"]["state"],
                    }
                elif (
                    msg["header"]["msg_type"] == "status"
                    and msg["parent_header"].get("msg_id") == last
                    and c.get("execution_state") == "idle"
                ):
                    break
            self.stats["panel"].append(time.monotonic() - t0)
            self.stats["html"].append(t_html)
        except Exception as exc:  # a page that never came counts as a failure
            self.stats["failed"].append(f"{type(exc).__name__}: {exc}")
            return
        sliders = {
            m: s["state"] for m, s in states.items() if s["model_name"] == "FloatSliderModel"
        }
        images = [m for m, s in states.items() if s["model_name"] == "ImageModel"]
        wn = [m for m, st in sliders.items() if st.get("max") == 100.0] or list(sliders)
        slider, image = wn[0], images[0]
        lo, hi = sliders[slider]["min"], sliders[slider]["max"]
        rng = random.Random(self.idx)
        t_end = time.monotonic() + duration
        try:
            while time.monotonic() < t_end:
                t_next = time.monotonic() + self.period
                value = float(round(rng.uniform(lo + 0.1 * (hi - lo), lo + 0.6 * (hi - lo))))
                ts = time.monotonic()
                await ws.write_message(
                    _msg(
                        self.session,
                        "comm_msg",
                        {
                            "comm_id": slider,
                            "data": {
                                "method": "update",
                                "state": {"value": value},
                                "buffer_paths": [],
                            },
                        },
                    )[0],
                    binary=True,
                )
                got = False
                while not got:
                    left = ts + self.timeout - time.monotonic()
                    if left <= 0:
                        break
                    try:
                        frame = await asyncio.wait_for(ws.read_message(), left)
                    except asyncio.TimeoutError:
                        break
                    if frame is None:
                        raise ConnectionError("websocket closed")
                    msg = _decode(frame)
                    c = msg.get("content", {})
                    if (
                        msg["header"]["msg_type"] == "comm_msg"
                        and c.get("comm_id") == image
                        and c.get("data", {}).get("method") == "update"
                        and (
                            ["value"] in c["data"].get("buffer_paths", [])
                            or "value" in c["data"].get("state", {})
                        )
                    ):
                        got = True
                if got:
                    self.stats["slider"].append(time.monotonic() - ts)
                else:
                    self.stats["timeouts"] += 1
                await asyncio.sleep(max(0.0, t_next - time.monotonic()))
        except Exception as exc:
            self.stats["failed"].append(f"{type(exc).__name__}: {exc}")
        finally:
            ws.close()


# ----------------------------------------------------------------------------- a class
def run_class(n, minutes, pool, after=60.0, period=2.0, extra=()):
    """Run ``n`` students for ``minutes`` against a fresh class page; return the row."""
    from tornado.httpclient import AsyncHTTPClient

    AsyncHTTPClient.configure(None, max_clients=max(10, 2 * n))
    server = Server(pool, extra)
    mem = {"peak": 0}
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            mem["peak"] = max(mem["peak"], server.rss())
            stop.wait(2.0)

    try:
        t_ready = server.wait_ready(600)
        rss_idle = server.rss()
        threading.Thread(target=sample, daemon=True).start()
        stats = {"panel": [], "html": [], "slider": [], "timeouts": 0, "failed": []}
        base = f"http://127.0.0.1:{server.port}"

        async def main():
            await asyncio.gather(
                *(
                    Student(i, base, stats, period).run(60.0 * minutes, random.uniform(0, 2))
                    for i in range(n)
                )
            )

        t0 = time.monotonic()
        asyncio.run(main())
        wall = time.monotonic() - t0
        load = os.getloadavg()[0]
        alive_close = server.kernels()
        time.sleep(after)
        alive_after = server.kernels()
        stop.set()
        return {
            "n": n,
            "pool": pool,
            "ready_s": t_ready,
            "rss_idle": rss_idle,
            "rss_peak": mem["peak"],
            "wall": wall,
            "load1": load,
            "alive_close": alive_close,
            "alive_after": alive_after,
            "after": after,
            **stats,
        }
    finally:
        stop.set()
        server.stop()


def _pct(xs, q):
    if not xs:
        return float("nan")
    xs = sorted(xs)
    i = min(len(xs) - 1, max(0, int(round(q / 100.0 * (len(xs) - 1)))))
    return xs[i]


def table(rows):
    head = (
        f"{'N':>3} {'pool':>4} | {'panel p50':>9} {'panel max':>9} {'<=5 s':>6} | "
        f"{'slider p50':>10} {'p90':>6} {'max':>6} {'moves':>6} {'lost':>5} | "
        f"{'RSS idle':>8} {'RSS peak':>8} {'GB/stud':>7} | {'kernels':>7} {'after':>9} | {'load1':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        ok5 = sum(1 for t in r["panel"] if t <= 5.0)
        per = (r["rss_peak"] - r["rss_idle"]) / max(1, r["n"]) / 1e9
        lines.append(
            f"{r['n']:>3} {r['pool']:>4} | {_pct(r['panel'], 50):>8.1f}s "
            f"{max(r['panel'] or [float('nan')]):>8.1f}s "
            f"{ok5:>3}/{r['n']:<2} | {_pct(r['slider'], 50):>9.2f}s {_pct(r['slider'], 90):>5.2f}s "
            f"{max(r['slider'] or [float('nan')]):>5.2f}s {len(r['slider']):>6} "
            f"{r['timeouts'] + len(r['failed']):>5} | "
            f"{r['rss_idle'] / 1e9:>6.2f}GB {r['rss_peak'] / 1e9:>6.2f}GB {per:>7.2f} | "
            f"{r['alive_close']:>7} {r['alive_after']:>3}@{r['after']:>3.0f}s | {r['load1']:>5.1f}"
        )
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks class", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--n", default="1,10,30", help="class sizes, comma separated (default 1,10,30)")
    ap.add_argument(
        "--minutes", type=float, default=3.0, help="slider minutes per student (default 3)"
    )
    ap.add_argument(
        "--pool",
        default="n",
        help="kernels kept pre-executed: a number, or 'n' for one per student (default)",
    )
    ap.add_argument(
        "--after",
        type=float,
        default=60.0,
        help="seconds after the last tab closed before counting live kernels (default 60)",
    )
    ap.add_argument(
        "--period", type=float, default=2.0, help="seconds between slider moves (default 2)"
    )
    args = ap.parse_args([] if argv is None else argv)
    rows = []
    for n in [int(x) for x in args.n.split(",") if x.strip()]:
        pool = n if args.pool == "n" else int(args.pool)
        print(
            f"class: N={n} pool={pool} {args.minutes:g} min (load {os.getloadavg()[0]:.1f}) ...",
            flush=True,
        )
        r = run_class(n, args.minutes, pool, after=args.after, period=args.period)
        if r["failed"]:
            print(f"  {len(r['failed'])} students failed, first: {r['failed'][0]}", flush=True)
        print(f"  pool of {pool} filled {r['ready_s']:.0f} s after start", flush=True)
        rows.append(r)
        print(table(rows[-1:]), flush=True)
    print(
        "\nclass page (python -m jerklab.app), websocket students moving a slider every "
        f"{args.period:g} s for {args.minutes:g} min; {os.cpu_count()} cores"
    )
    print(table(rows))
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
