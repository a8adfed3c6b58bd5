"""The class page's shared rig: jerklab.broker queues runs from many kernels on one rig.

A virtual rig at real-time pace sits behind the broker; clients are threads with their own
connections, as the page's kernels would be.
"""

from __future__ import annotations

import json
import socket
import tempfile
import threading
import time
from pathlib import Path

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


#: a move of about 4 s, so that a second client surely arrives while it runs
LONG_MOVE = dict(tuning.DEFAULT_MOVE, distance=100.0)

#: a move of about 2 s (1.96 s planned, and the settle), whose samples the broker streams
STREAM_MOVE = dict(tuning.DEFAULT_MOVE, distance=50.0)


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


def test_the_class_page_on_a_running_broker(broker, monkeypatch):
    """``jerklab app --rig broker://host:port`` hands the page's kernels that broker and
    starts none (a second broker would open the rig a second time); a bad address is refused
    naming ``--rig``."""
    voila_app = pytest.importorskip("voila.app")
    from jerklab import app

    seen = {}
    monkeypatch.setattr(
        voila_app, "main", lambda argv: seen.setdefault("env", app.os.environ[app.RIG_ENV])
    )

    def no_second_broker(*args, **kwargs):
        raise AssertionError(f"a broker was started for {args}")

    monkeypatch.setattr(app, "start_broker", no_second_broker)
    # set, then removed: monkeypatch restores the variable's absence after app.main sets it
    monkeypatch.setenv(app.RIG_ENV, "")
    monkeypatch.delenv(app.RIG_ENV)
    app.main(["--rig", broker.address, "--pool", "0"])
    assert seen["env"] == broker.address
    p = app.panel_for_page(rig_port=seen["env"])
    assert isinstance(p.rig, BrokerRig) and (p.rig.host, p.rig.port) == parse_address(
        broker.address
    )
    with pytest.raises(SystemExit):
        app.main(["--rig", "broker://127.0.0.1", "--pool", "0"])


# ---------------------------------------------------------------------- the run's live stream
def _watched_run(address, name, move, events):
    """A BrokerRig run whose statuses and streamed batches land in ``events`` as
    ``(clock, "status" | "batch" | "done", what)``; a batch keeps a copy of its rows so far."""
    rig = BrokerRig(address, client=name)
    rec = rig.run_move(
        tuning.move_profile(move),
        tuning.compute_pole_placement().gains,
        path=False,
        on_status=lambda m: events.append((time.monotonic(), "status", m)),
        on_batch=lambda r: events.append((time.monotonic(), "batch", r.rows())),
    )
    events.append((time.monotonic(), "done", rec))
    return rec


@pytest.mark.slow  # seconds of runs in real time
def test_a_run_streams_its_samples_to_its_own_client_only(broker):
    """A 2 s move through the broker: its client hears batches during the run (>= 3, spread
    over the run, each a prefix of the final recording); the final recording is the one of
    the same run made directly on a fresh virtual rig; a second client, queued meanwhile,
    hears none of them."""
    t0 = time.monotonic()
    first, second = [], []
    t = threading.Thread(target=_watched_run, args=(broker.address, "first", STREAM_MOVE, first))
    t.start()
    while not any(k == "batch" for _, k, _ in first) and time.monotonic() - t0 < 10:
        time.sleep(0.02)
    # the second client queues while the first one's run streams
    t2 = threading.Thread(target=_watched_run, args=(broker.address, "second", None, second))
    t2.start()
    t.join(30)
    t2.join(30)
    end, kind, rec = first[-1]
    assert kind == "done", first
    final = rec.rows()
    batches = [(when, rows) for when, k, rows in first if k == "batch"]
    during = [(when, rows) for when, rows in batches if len(rows) < len(final)]
    assert len(during) >= 3, ([len(r) for _, r in batches], broker.streams, first[:3])
    assert during[-1][0] - during[0][0] >= 1.0  # they arrive as the 2 s run goes, not at once
    sizes = [len(rows) for _, rows in batches]
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes)
    for _, rows in batches:
        assert rows == final[: len(rows)]
    # streaming does not change the recording: the same run on a fresh virtual rig
    direct = connect(progress=False).run_move(
        tuning.move_profile(STREAM_MOVE), tuning.compute_pole_placement().gains, path=False
    )
    assert rec.metadata["status"] == "complete" and direct.rows() == final
    # the second client: queued behind the first, no batch before its own run started
    kinds = [(k, m if k == "status" else None) for _, k, m in second]
    start2 = kinds.index(("status", "running on the rig…"))
    assert kinds[0] == ("status", "queued: 1 ahead of you"), kinds
    assert all(k == "status" for k, _ in kinds[:start2]), kinds
    final2 = second[-1][2].rows()
    assert final2 != final[: len(final2)]
    for _, k, rows in second:
        if k == "batch":
            assert rows == final2[: len(rows)]
    assert [s["identity"] for s in broker.streams] == ["first", "second"]
    assert time.monotonic() - t0 < 15


@pytest.mark.slow  # seconds of runs in real time
def test_a_client_that_does_not_read_its_stream_does_not_hold_up_the_rig(broker):
    """A client asks for the stream of a 2 s run with a tiny receive buffer and reads nothing
    until the run is over: the rig finishes in the run's own time, and the client then reads
    contiguous batches and the whole final recording."""
    gains = tuning.compute_pole_placement().gains
    profile = tuning.move_profile(STREAM_MOVE)
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
    s.connect(parse_address(broker.address))
    g = {k: getattr(gains, k) for k in ("kpd", "kid", "kdd", "Ts", "gamma", "loop")}
    req = {
        "op": "run_move",
        "client": "sleeper",
        "profile": dict(kind="sine_jerk", **STREAM_MOVE),
        "gains": g,
        "stream": True,
    }
    t0 = time.monotonic()
    s.sendall((json.dumps(req) + "\n").encode())
    while broker.runs_done < 1 and time.monotonic() - t0 < 15:
        time.sleep(0.02)
    took = time.monotonic() - t0
    planned = profile.duration + 0.25  # the move and the default settle
    assert broker.runs_done == 1 and took < planned + 1.5, (took, planned)
    s.settimeout(10)
    msgs = [json.loads(line) for line in s.makefile("rb")]
    s.close()
    assert [m for m in msgs if "queued" in m or "running" in m][-1] == {"running": True}
    rows = []
    for m in msgs:
        if "samples" in m:
            assert m["samples"]["start"] == len(rows)
            rows += [tuple(r) for r in m["samples"]["rows"]]
    done = msgs[-1]
    assert done.get("done") is True, done.keys()
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "run.csv").write_text(done["csv"], encoding="ascii")
        (Path(tmp) / "run.json").write_text(done["json"], encoding="utf-8")
        rec = Recording.load(Path(tmp) / "run.csv")
    direct = connect(progress=False).run_move(profile, gains, path=False)
    assert rec.metadata["status"] == "complete" and rec.rows() == direct.rows()
    assert 0 < len(rows) <= len(rec) and rec.rows()[: len(rows)] == rows


class _FullSocket:
    """A non-blocking socket stand-in that takes at most ``room`` bytes until ``read``."""

    def __init__(self, room):
        self.room = room
        self.out = b""

    def send(self, data):
        if self.room <= 0:
            raise BlockingIOError
        n = min(self.room, len(data))
        self.out += data[:n]
        self.room -= n
        return n

    def sendall(self, data):
        self.out += data

    def read(self, room):
        self.room = room


def test_the_stream_holds_one_batch_at_most_and_loses_no_row():
    """broker._Stream against a socket that fills up: while a batch is not written out no
    new one is made (the rows wait in the recording), the next batch takes them all, and
    what reaches the socket parses into the recording's rows, contiguous, in whole lines."""
    from jerklab.broker import _Stream

    rec = Recording({"kind": "move", "Ts": 0.005, "counts_per_rad": 71.3, "volts_per_pwm": 0.01})
    now = [0.0]
    sock = _FullSocket(room=150)
    st = _Stream(sock, threading.Lock(), interval=0.1, max_rows=50, clock=lambda: now[0])
    k = 0
    pending_sizes = []
    for tick in range(40):
        for _ in range(20):  # 20 samples every 0.1 s: 200 a second
            rec.append(k, 0.001 * k, 3 * k, (-1) ** k * k, k % 2)
            k += 1
        now[0] = 0.1 * tick
        st.tick(rec)
        pending_sizes.append(len(st.pending))
        if tick == 20:
            sock.read(10**6)  # the client reads again
    assert st.held >= 15  # ticks 1..19 found the socket full
    assert st.batches < 40 and st.rows_sent <= len(rec)
    one_batch = 50 * 60 + 300  # 50 rows of at most ~60 bytes and the envelope
    assert max(pending_sizes) <= one_batch
    st.drain()
    lines = sock.out.decode().split("\n")
    assert lines[-1] == ""  # whole lines only
    rows = []
    for i, line in enumerate(lines[:-1]):
        batch = json.loads(line)["samples"]
        assert batch["start"] == len(rows) and len(batch["rows"]) <= 50
        assert ("meta" in batch) == (i == 0)
        rows += [tuple(r) for r in batch["rows"]]
    assert rows == rec.rows(0, len(rows)) and len(rows) == st.rows_sent
    first = json.loads(lines[0])["samples"]["meta"]
    assert first == {
        "kind": "move",
        "Ts": 0.005,
        "counts_per_rad": 71.3,
        "volts_per_pwm": 0.01,
        "total": 0,
    }


def test_the_live_box_names_no_server_address(broker, monkeypatch):
    """The live plot of a shared-rig run is titled for the student ("shared rig: move"), not
    with the broker's host and port (the class page shows no server detail)."""
    import jerklab.broker as B

    labels = []
    real = B._LiveView

    def spy(enabled, on_batch, label, *rest):
        labels.append(label)
        return real(enabled, on_batch, label, *rest)

    monkeypatch.setattr(B, "_LiveView", spy)
    rig = BrokerRig(broker.address, client="alice")
    rig.run_move(
        tuning.move_profile(dict(tuning.DEFAULT_MOVE, distance=2.0)),
        tuning.compute_pole_placement().gains,
        path=False,
    )
    host, port = parse_address(broker.address)
    assert labels == ["shared rig: move"]
    assert str(port) not in labels[0] and host not in labels[0]
