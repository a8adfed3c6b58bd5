"""Attacks on the class page's rig queue (issue 32, "Class page and rig queue"), run as a student's
kernel would run them: raw JSON lines over TCP to the broker on 127.0.0.1, or the page's own
client. Each of these passed on the broker before the fix (see the notes in each test).

The broker here identifies a request by a token through ``authenticate`` (on the hub that is
:class:`jerklab.hubauth.HubIdentity`, tested against a real hub in tests/security/test_hub.py);
here a table of two students' tokens stands in for the hub.
"""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from jerklab import tuning
from jerklab.broker import (
    BrokerError,
    BrokerRig,
    Limits,
    RigBroker,
    parse_address,
    unique_run_name,
)
from jerklab.rig import Recording

TOKENS = {"tok-alice-0123456789": "alice", "tok-bob-9876543210": "bob"}

#: about 2 s on the virtual rig at real-time pace
LONG_MOVE = dict(tuning.DEFAULT_MOVE, distance=100.0)


def _hub_table(token):
    if token not in TOKENS:
        raise PermissionError("token: the hub knows no user with this token")
    return TOKENS[token]


def _request(profile=None, token=None, client="kernel", settle=0.25):
    req = {
        "op": "run_move",
        "client": client,
        "profile": dict(kind="sine_jerk", **(profile or tuning.DEFAULT_MOVE)),
        "gains": {"kpd": 4.5, "kid": 0.2, "kdd": 21.6, "Ts": 0.005},
        "settle": settle,
    }
    if token is not None:
        req["token"] = token
    return req


def _first_reply(address, req, timeout=10.0):
    """Send one request as raw JSON, return (socket, first message); the socket stays open."""
    s = socket.create_connection(parse_address(address), timeout=timeout)
    s.sendall((json.dumps(req) + "\n").encode())
    f = s.makefile("rb")
    return s, f, json.loads(f.readline())


@pytest.fixture
def broker(tmp_path):
    b = RigBroker(None, speed=1.0, authenticate=_hub_table, recordings=tmp_path / "broker")
    try:
        yield b
    finally:
        b.close()


def test_queue_flood_is_refused_and_a_classmate_waits_one_run_at_most(broker):
    """20 runs from one student, then a classmate's. Before: all 20 queued (bob waited for
    every one of them: 40 s here, 218 s in the report)."""
    gains = tuning.compute_pole_placement().gains
    conns, replies = [], []
    for i in range(20):  # even under twenty labels, the hub's token is the same student
        s, f, first = _first_reply(
            broker.address, _request(LONG_MOVE, "tok-alice-0123456789", client=f"bob{i}")
        )
        conns.append(s)
        replies.append(first)
    try:
        queued = [r for r in replies if "queued" in r]
        refused = [r for r in replies if "error" in r]
        assert len(queued) == 1 and len(refused) == 19, replies
        assert all("MAX_RUNS_PER_STUDENT = 1" in r["error"] for r in refused), refused[0]
        assert all(r["type"] == "QueueFullError" for r in refused)
        # bob's run waits at most the one run of alice's (~2 s), bounded by the limits
        t0 = time.monotonic()
        rig = BrokerRig(broker.address, token="tok-bob-9876543210", timeout=10.0)
        rec = rig.run_move(tuning.move_profile(), gains, path=False)
        waited = time.monotonic() - t0
        bound = broker.limits.max_duration + broker.limits.max_settle + 2 * 1.0 + 3.0
        assert waited < bound, (waited, bound)
        assert rec.metadata["student"] == "bob" and rec.metadata["identity"] == "hub"
        assert broker.order == ["alice", "bob"]
    finally:
        for s in conns:
            s.close()


def test_oversized_moves_are_refused_naming_the_limit(broker):
    """A 400 rad move, a move planned to last minutes, a settle of 1000 s. Before: all run."""
    cases = [
        (dict(tuning.DEFAULT_MOVE, distance=400.0), 0.25, "max_distance = 120 rad"),
        (dict(tuning.DEFAULT_MOVE, distance=100.0, max_velocity=1.0), 0.25, "max_duration = 5 s"),
        (tuning.DEFAULT_MOVE, 1000.0, "max_settle = 2 s"),
        (dict(tuning.DEFAULT_MOVE, distance=float("1e300")), 0.25, "max_distance"),
    ]
    for move, settle, limit in cases:
        s, f, reply = _first_reply(
            broker.address, _request(move, "tok-alice-0123456789", settle=settle)
        )
        s.close()
        assert reply.get("type") == "LimitError" and limit in reply["error"], (move, reply)
    assert broker.runs_done == 0 and broker.order == []
    # the limits are the broker's own, stated to every client
    rig = BrokerRig(broker.address, token="tok-alice-0123456789")
    assert rig.info["limits"] == {"max_distance": 120.0, "max_duration": 5.0, "max_settle": 2.0}
    with pytest.raises(BrokerError, match="max_distance"):
        rig.run_move(
            tuning.move_profile(dict(tuning.DEFAULT_MOVE, distance=400.0)),
            tuning.compute_pole_placement().gains,
            path=False,
        )


def test_a_typed_name_writes_only_into_ones_own_recordings(broker, tmp_path):
    """Alice's kernel says it is bob. Before: the run went into recordings/bob/ as bob's."""
    rig = BrokerRig(broker.address, token="tok-alice-0123456789", client="bob")
    assert rig.identity == "alice" and rig.verified
    rec = rig.run_move(tuning.move_profile(), tuning.compute_pole_placement().gains, path=False)
    assert rec.metadata["student"] == "alice" and rec.metadata["identity"] == "hub"
    assert broker.order == ["alice"]
    saved = sorted((tmp_path / "broker").rglob("*.csv"))
    assert [p.parent.name for p in saved] == ["alice"]
    assert Recording.load(saved[0]).metadata["student"] == "alice"
    assert not (tmp_path / "broker" / "bob").exists()


def test_no_token_or_a_forged_token_is_refused(broker):
    """Before: the broker had no login at all."""
    for token in (None, "", "tok-bob-0000000000", "x" * 10_000, ["tok-bob-9876543210"]):
        req = _request(token=None)
        if token is not None:
            req["token"] = token
        s, f, reply = _first_reply(broker.address, req)
        s.close()
        assert "error" in reply and reply["type"] in ("PermissionError", "HubAuthError"), reply
    with pytest.raises(BrokerError, match="token"):
        BrokerRig(broker.address, token="")
    assert broker.runs_done == 0


def test_two_runs_in_one_second_get_two_files(tmp_path, monkeypatch):
    """The page's client saving to the recordings folder. Before: both runs were named
    <second>_move.csv and the later overwrote the earlier."""
    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path / "rec"))
    fast = dict(tuning.DEFAULT_MOVE, distance=0.5)
    with RigBroker(None, speed=50.0, recordings=tmp_path / "broker") as b:
        gains = tuning.compute_pole_placement().gains
        out, errors = [], []

        def run(i):
            try:
                out.append(
                    BrokerRig(b.address, client=f"s{i}").run_move(
                        tuning.move_profile(fast), gains, settle=0.0
                    )
                )
            except Exception as exc:  # noqa: BLE001 - reported below
                errors.append(exc)

        threads = [threading.Thread(target=run, args=(i,)) for i in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        assert not errors, errors
    local = sorted((tmp_path / "rec").glob("*.csv"))
    kept = sorted((tmp_path / "broker").rglob("*.csv"))
    assert len(local) == 3 and len({p.name for p in local}) == 3, local
    assert len(kept) == 3 and len({p.name for p in kept}) == 3, kept
    # unverified labels are written as such
    assert {Recording.load(p).metadata["identity"] for p in kept} == {"unverified"}
    assert {r.csv_path.name for r in out} == {p.name for p in local}
    # names made within one microsecond differ too
    assert len({unique_run_name() for _ in range(1000)}) == 1000


def test_limits_and_authenticate_are_checked():
    with pytest.raises(TypeError, match="authenticate"):
        RigBroker(None, authenticate="alice")
    with pytest.raises(TypeError, match="limits"):
        RigBroker(None, limits={"max_distance": 1.0})
    lim = Limits(max_distance=1.0)
    with pytest.raises(ValueError, match="max_distance = 1 rad"):
        lim.check(1.5, 0.1, 0.1)


# ---------------------------------------------------------------------------- the class page
V1 = "v1.kernel.websocket.jupyter.org"


@pytest.mark.slow
def test_a_crafted_kernel_websocket_does_not_freeze_the_class_page(tmp_path):
    """Voila's upstream hang, tried on ``python -m jerklab.app`` as documented. Before: a
    websocket without the v1 subprotocol sending a legacy binary frame that declares 2**31
    parts, or a v1 frame that declares 2**62 offsets, froze the server (no answer in 15 s)."""
    import os
    import re
    import signal
    import subprocess
    import sys
    import urllib.request

    websocket = pytest.importorskip("websocket")
    pytest.importorskip("voila")
    from jupyter_server.services.kernels.connection.base import (
        deserialize_msg_from_ws_v1,
        serialize_msg_to_ws_v1,
    )

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(
        os.environ,
        JUPYTER_RUNTIME_DIR=str(tmp_path / "runtime"),
        JUPYTER_DATA_DIR=str(tmp_path / "data"),
        JERKLAB_RECORDINGS=str(tmp_path / "recordings"),
        MPLBACKEND="Agg",
    )
    log = open(tmp_path / "server.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jerklab.app", f"--port={port}", "--pool=0"],
        env=env,
        cwd=tmp_path,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        t0 = time.monotonic()
        while True:
            try:
                with urllib.request.urlopen(base + "/", timeout=120) as r:
                    page = r.read().decode()
                break
            except OSError:
                assert proc.poll() is None and time.monotonic() - t0 < 180, "page did not start"
                time.sleep(0.5)
        # the page shows no server path and runs without tracebacks
        assert str(tmp_path) not in page and "Traceback" not in page
        kernel = re.search(r'kernelId["\']?\s*[:=]\s*["\']([0-9a-f-]{36})', page).group(1)
        ws_url = f"ws://127.0.0.1:{port}/api/kernels/{kernel}/channels"

        def page_answers():
            t = time.monotonic()
            with urllib.request.urlopen(f"{base}/api/kernels/{kernel}", timeout=15) as r:
                assert r.status == 200
            return time.monotonic() - t

        attacks = [
            (None, b"\x7f\xff\xff\xff" + b"\0" * 8),  # legacy frame: 2**31 - 1 parts
            ([V1], (2**62).to_bytes(8, "little") + b"\0" * 16),  # v1 frame: 2**62 offsets
        ]
        for subprotocols, frame in attacks:
            try:
                ws = websocket.create_connection(ws_url, timeout=10, subprotocols=subprotocols)
            except websocket.WebSocketBadStatusException as exc:
                assert subprotocols is None and exc.status_code == 400  # refused at the door
            else:
                try:
                    ws.send_binary(frame)
                    time.sleep(1.0)
                finally:
                    ws.close()
            assert page_answers() < 5.0
        # the page's own protocol still works: a kernel_info round trip in v1 frames
        ws = websocket.create_connection(ws_url, timeout=30, subprotocols=[V1])
        try:
            assert ws.getsubprotocol() == V1
            msg_id = "jerklab-guard-test"
            header = {
                "msg_id": msg_id,
                "msg_type": "kernel_info_request",
                "username": "t",
                "session": "s",
                "version": "5.3",
                "date": "",
            }
            parts = [json.dumps(x).encode() for x in (header, {}, {}, {})]
            ws.send_binary(serialize_msg_to_ws_v1(parts, "shell"))
            t0 = time.monotonic()
            while time.monotonic() - t0 < 30:
                channel, msg_list = deserialize_msg_from_ws_v1(ws.recv())
                parent = json.loads(msg_list[1])
                kind = json.loads(msg_list[0])["msg_type"]
                if parent.get("msg_id") == msg_id and kind == "kernel_info_reply":
                    assert channel == "shell"
                    break
            else:
                pytest.fail("no kernel_info_reply through the guarded websocket")
        finally:
            ws.close()
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the frozen server of the old code ignores SIGTERM
        proc.wait(30)
        log.close()
