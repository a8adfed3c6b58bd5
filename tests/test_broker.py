"""The class page's shared rig: jerklab.broker queues runs from many kernels on one rig.

A virtual rig at real-time pace sits behind the broker; clients are threads with their own
connections, as the page's kernels would be.
"""

from __future__ import annotations

import json
import socket
import threading
import time

import numpy as np
import pytest

from jerklab import tuning
from jerklab.broker import BrokerError, BrokerRig, RigBroker, parse_address
from jerklab.rig import Recording, connect


@pytest.fixture
def broker():
    b = RigBroker(None, speed=1.0)
    try:
        yield b
    finally:
        b.close()


#: a move of about 2 s, so that a second client surely arrives while it runs
LONG_MOVE = dict(tuning.DEFAULT_MOVE, distance=100.0)


def _client(address, name, delay, out, path=False, running=None, move=None):
    if isinstance(delay, threading.Event):
        assert delay.wait(30)
    else:
        time.sleep(delay)
    msgs = []
    out[name] = msgs

    def status(m):
        msgs.append((time.monotonic(), m))
        if running is not None and m.startswith("running"):
            running.set()

    try:
        rig = BrokerRig(address, client=name)
        rec = rig.run_move(
            tuning.move_profile(move),
            tuning.compute_pole_placement().gains,
            path=path,
            on_status=status,
        )
        msgs.append((time.monotonic(), rec))
    except Exception as exc:  # reported by the test
        msgs.append((time.monotonic(), exc))


def test_two_concurrent_clients_are_queued_fifo(broker, tmp_path):
    out = {}
    running = threading.Event()
    threads = [
        threading.Thread(
            target=_client,
            args=(
                broker.address,
                "first",
                0.0,
                out,
                tmp_path / "first" / "run",
                running,
                LONG_MOVE,
            ),
        ),
        threading.Thread(
            target=_client,
            args=(broker.address, "second", running, out, tmp_path / "second" / "run"),
        ),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    first, second = out["first"], out["second"]
    assert isinstance(first[-1][1], Recording) and isinstance(second[-1][1], Recording), out
    # the second was told it waits behind one run, and only ran after the first one finished
    texts = [m for _, m in second if isinstance(m, str)]
    assert texts[0] == "queued: 1 ahead of you", texts
    start2 = next(t for t, m in second if m == "running on the rig…")
    end1 = first[-1][0]
    assert start2 >= end1 - 0.2, (start2, end1)
    assert broker.order == ["first", "second"] and broker.runs_done == 2
    # both runs are whole and agree with a run made directly on a fresh virtual rig
    gains = tuning.compute_pole_placement().gains
    for name, move in (("first", LONG_MOVE), ("second", None)):
        direct = connect(progress=False).run_move(tuning.move_profile(move), gains, path=False)
        rec = out[name][-1][1]
        assert rec.metadata["status"] == "complete"
        # the shared motor starts the second run where the first left it (within a count)
        assert rec.counts.size == direct.counts.size
        assert np.max(np.abs(rec.counts - direct.counts)) <= 1
        assert np.array_equal(Recording.load(tmp_path / name / "run.csv").counts, rec.counts)


def test_a_client_that_leaves_the_queue_is_dropped(broker):
    out = {}
    running = threading.Event()
    t1 = threading.Thread(
        target=_client, args=(broker.address, "a", 0.0, out, False, running, LONG_MOVE)
    )
    t1.start()
    assert running.wait(30)
    # a client queues, then hangs up while waiting
    s = socket.create_connection(parse_address(broker.address))
    req = {
        "op": "run_move",
        "client": "quitter",
        "profile": dict(kind="sine_jerk", **tuning.DEFAULT_MOVE),
        "gains": {"kpd": 4.5, "kid": 0.2, "kdd": 21.6, "Ts": 0.005},
    }
    s.sendall((json.dumps(req) + "\n").encode())
    assert json.loads(s.makefile().readline())["queued"] == 1
    s.close()
    t3 = threading.Thread(target=_client, args=(broker.address, "c", 0.0, out))
    t3.start()
    t1.join(60)
    t3.join(60)
    assert isinstance(out["c"][-1][1], Recording), out["c"]
    assert "quitter" not in broker.order and broker.order == ["a", "c"]


def test_broker_refuses_unstable_gains_and_bad_requests(broker):
    bad = tuning.compute_pole_placement(wn=35.0, Ts=0.011, design="z-domain").gains
    rig = BrokerRig(broker.address)
    with pytest.raises(BrokerError, match=r"UnstableDesignError.*\|z\| = 1\.\d+"):
        rig.run_move(tuning.move_profile(), bad, path=False)
    # refused before it queues: it never reached the rig
    assert broker.order == [] and broker.runs_done == 0
    assert [who for who, _ in broker.refused] == ["kernel"]
    s = socket.create_connection(parse_address(broker.address))
    s.sendall(b'{"op": "format c:"}\n')
    assert "op must be" in json.loads(s.makefile().readline())["error"]
    s.close()


def test_unreachable_broker_and_bad_address():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(BrokerError, match="cannot reach the rig broker"):
        BrokerRig(f"broker://127.0.0.1:{port}", timeout=2.0)
    for bad in ("127.0.0.1:5000", "broker://host", "broker://:99", "broker://h:0", None):
        with pytest.raises(ValueError, match="address"):
            parse_address(bad)


def test_class_page_panel_runs_through_the_broker(broker, tmp_path, monkeypatch):
    """The page's panel on a broker:// address: queued run, saved under the student's ID."""
    from jerklab.app import panel_for_page

    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path))
    p = panel_for_page(rig_port=broker.address)
    assert isinstance(p.rig, BrokerRig)
    p.student.value = "s123"
    seen = []
    p.rig_status.observe(lambda c: seen.append(c["new"]), names="value")
    t, err = p.run_on_rig()
    assert any(v.startswith("queued") for v in seen) and any("running" in v for v in seen), seen
    assert broker.order == ["s123"]
    files = list((tmp_path / "s123").glob("*_move.csv"))
    assert len(files) == 1 and Recording.load(files[0]).metadata["broker"] == broker.address
    # the student's folder and file name, never the server's absolute path
    assert "saved as" in p.rig_status.value and f"s123/{files[0].name}" in p.rig_status.value
    assert str(tmp_path) not in p.rig_status.value
    assert (
        abs(float(np.max(np.abs(err))) - float(np.max(np.abs(p.result.err_move_measured)))) < 0.05
    )
