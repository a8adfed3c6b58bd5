"""The class page's attacks of issue 32 (rig queue, Voilà), for ``python -m benchmarks security``.

Each is tried as a student's kernel would: raw JSON lines to the broker on 127.0.0.1, a crafted
websocket to ``python -m jerklab.app``. The same attacks, with assertions, are
tests/security/test_queue.py; the hub's own (logins, a kernel reading a classmate's files) need
root and real Unix users and are tests/security/test_hub.py. Written against the broker's wire
protocol, so that the same functions also run on a checkout from before the fix.
"""

from __future__ import annotations

import inspect
import json
import os
import pathlib
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request

from benchmarks.bench_security import Skip, attack

TOKENS = {"tok-alice-0123456789": "alice", "tok-bob-9876543210": "bob"}
MOVE = dict(distance=10.0, max_jerk=5000.0, max_accel=300.0, max_velocity=60.0)


def _table(token):
    if token not in TOKENS:
        raise PermissionError("token: unknown")
    return TOKENS[token]


def _broker(speed=1.0, **kw):
    """A broker with the hub's token table where the broker supports one."""
    from jerklab.broker import RigBroker

    params = inspect.signature(RigBroker).parameters
    kw = {k: v for k, v in kw.items() if k in params}
    if "authenticate" in params:
        kw["authenticate"] = _table
    return RigBroker(None, speed=speed, **kw)


def _req(move=None, token="tok-alice-0123456789", client="alice", settle=0.25):
    return {
        "op": "run_move",
        "client": client,
        "token": token,
        "profile": dict(kind="sine_jerk", **(move or MOVE)),
        "gains": {"kpd": 4.5, "kid": 0.2, "kdd": 21.6, "Ts": 0.005},
        "settle": settle,
    }


def _send(broker, req):
    from jerklab.broker import parse_address

    s = socket.create_connection(parse_address(broker.address), timeout=10)
    s.sendall((json.dumps(req) + "\n").encode())
    f = s.makefile("rb")
    return s, f, json.loads(f.readline())


def _final(f, timeout=30.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        msg = json.loads(f.readline())
        if "done" in msg or "error" in msg:
            return msg
    raise TimeoutError("no final answer")


@attack("queue", "one student floods the queue with 20 runs")
def flood():
    b = _broker()
    conns = []
    try:
        firsts = []
        for i in range(20):
            s, f, first = _send(b, _req(dict(MOVE, distance=100.0), client=f"bob{i}"))
            conns.append(s)
            firsts.append(first)
        queued = sum("queued" in r for r in firsts)
        return queued <= 1, f"{queued} of 20 queued"
    finally:
        for s in conns:
            s.close()
        b.close()


@attack("queue", "a 400 rad move")
def far_move():
    b = _broker()
    try:
        s, f, first = _send(b, _req(dict(MOVE, distance=400.0)))
        s.close()
        return "error" in first, first.get("error", "queued")[:100]
    finally:
        b.close()


@attack("queue", "a settle of 1000 s")
def long_settle():
    b = _broker()
    try:
        s, f, first = _send(b, _req(settle=1000.0))
        s.close()
        return "error" in first, first.get("error", "queued")[:100]
    finally:
        b.close()


@attack("queue", "a run with no hub token")
def no_token():
    b = _broker(speed=20.0)
    try:
        req = _req()
        del req["token"]
        s, f, first = _send(b, req)
        reply = first if "error" in first else _final(f)
        s.close()
        return "error" in reply, reply.get("error", "ran")[:100]
    finally:
        b.close()


@attack("queue", "alice's kernel says it is bob")
def typed_id():
    with tempfile.TemporaryDirectory() as tmp:
        b = _broker(speed=20.0, recordings=pathlib.Path(tmp))
        try:
            s, f, first = _send(b, _req(client="bob"))
            reply = first if "error" in first else _final(f)
            s.close()
            meta = json.loads(reply["json"]) if "json" in reply else {}
            who = meta.get("student", "(no identity: the label 'bob' is taken as is)")
            return who == "alice", f"recorded as {who}"
        finally:
            b.close()


@attack("queue", "three runs in one second")
def same_second():
    from jerklab import tuning
    from jerklab.broker import BrokerRig

    with tempfile.TemporaryDirectory() as tmp:
        os.environ["JERKLAB_RECORDINGS"] = tmp
        b = _broker(speed=50.0)
        try:
            gains = tuning.compute_pole_placement().gains
            prof = tuning.move_profile(dict(MOVE, distance=0.5))
            kw = {"token": "tok-alice-0123456789"}
            if "token" not in inspect.signature(BrokerRig).parameters:
                kw = {}

            def one(i):
                BrokerRig(b.address, client=f"s{i}", **kw).run_move(prof, gains, settle=0.0)

            for i in range(3):  # one after another: one student's queue allows one at a time
                one(i)
            n = len(list(pathlib.Path(tmp).glob("*.csv")))
            return n == 3, f"{n} files for 3 runs"
        finally:
            os.environ.pop("JERKLAB_RECORDINGS", None)
            b.close()


_PAGE = {}


def _class_page():
    """``python -m jerklab.app --pool=0`` on a free port: (process, base URL, kernel id)."""
    try:
        import voila  # noqa: F401
        import websocket  # noqa: F401
    except ImportError as exc:
        raise Skip(f"needs voila and websocket-client ({exc.name})") from None
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    tmp = tempfile.mkdtemp(prefix="jerklab-bench-page-")
    env = dict(os.environ, JUPYTER_RUNTIME_DIR=tmp + "/rt", JERKLAB_RECORDINGS=tmp + "/rec")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jerklab.app", f"--port={port}", "--pool=0"],
        env=env,
        cwd=tmp,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    base = f"http://127.0.0.1:{port}"
    t0 = time.monotonic()
    while True:
        try:
            with urllib.request.urlopen(base + "/", timeout=120) as r:
                page = r.read().decode()
            break
        except OSError:
            if proc.poll() is not None or time.monotonic() - t0 > 180:
                os.killpg(proc.pid, signal.SIGKILL)
                raise RuntimeError("the class page did not start") from None
            time.sleep(0.5)
    kernel = re.search(r'kernelId["\']?\s*[:=]\s*["\']([0-9a-f-]{36})', page).group(1)
    return proc, base, kernel


def _hang(subprotocols, frame):
    import websocket

    proc, base, kernel = _class_page()
    try:
        url = base.replace("http", "ws") + f"/api/kernels/{kernel}/channels"
        try:
            ws = websocket.create_connection(url, timeout=10, subprotocols=subprotocols)
        except websocket.WebSocketBadStatusException as exc:
            refused = f"websocket refused ({exc.status_code}); "
        else:
            refused = ""
            ws.send_binary(frame)
            time.sleep(1.0)
            ws.close()
        t0 = time.monotonic()
        try:
            with urllib.request.urlopen(f"{base}/api/kernels/{kernel}", timeout=15):
                pass
            return True, f"{refused}page answered in {time.monotonic() - t0:.2f} s"
        except OSError:
            return False, f"{refused}page silent for 15 s"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # a frozen Voila ignores SIGTERM
        proc.wait(30)


@attack("class page", "legacy websocket, a frame declaring 2**31 parts")
def legacy_hang():
    return _hang(None, b"\x7f\xff\xff\xff" + b"\0" * 8)


@attack("class page", "v1 websocket, a frame declaring 2**62 offsets")
def v1_hang():
    return _hang(["v1.kernel.websocket.jupyter.org"], (2**62).to_bytes(8, "little") + b"\0" * 16)


@attack("class page", "Voila set to show tracebacks (server paths) on the page")
def page_paths():
    from jerklab import app

    argv = app.voila_argv()
    tracebacks = "--show_tracebacks=True" in argv
    return not tracebacks, f"Voila {'--show_tracebacks=True' if tracebacks else 'tracebacks off'}"


_HUB = {}
_HUB_TESTS = [
    ("test_a_student_logs_in_as_nobody_else", "log in as a classmate, as the admin, as root"),
    ("test_a_student_cannot_open_the_admin_page", "open /hub/admin and the admin API"),
    (
        "test_a_students_kernel_reads_neither_classmates_nor_the_hub",
        "a kernel reads ../bob, the hub's environ, cookie secret, database",
    ),
    ("test_the_rig_names_a_run_by_the_hub_login_not_a_typed_id", "run on the rig as bob"),
    (
        "test_a_legacy_kernel_websocket_is_refused_on_a_students_server",
        "a legacy kernel websocket on the hub",
    ),
]


def _hub_results():
    """Run tests/security/test_hub.py once (a real hub, real Unix users): {test: outcome}."""
    if "res" not in _HUB:
        root = pathlib.Path(__file__).resolve().parent.parent
        test = root / "tests" / "security" / "test_hub.py"
        if os.geteuid() != 0:
            raise Skip("needs root (the hub makes Unix users): see tests/security/test_hub.py")
        if not test.exists():
            raise Skip("tests/security/test_hub.py is not in this checkout")
        out = subprocess.run(
            [sys.executable, "-m", "pytest", str(test), "-q", "-rA", "-p", "no:randomly"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=900,
        ).stdout
        res = {}
        for line in out.splitlines():
            m = re.match(r"^(PASSED|FAILED|ERROR|SKIPPED)\S* .*::(test_\w+)", line)
            if m:
                res[m.group(2)] = m.group(1)
        _HUB["res"] = res
    return _HUB["res"]


def _hub_attack(test):
    def run():
        outcome = _hub_results().get(test, "not run")
        if outcome == "SKIPPED":
            raise Skip("the hub test skipped (a tool missing)")
        return outcome == "PASSED", f"tests/security/test_hub.py::{test}: {outcome}"

    return run


for _test, _name in _HUB_TESTS:
    attack("hub", _name)(_hub_attack(_test))
