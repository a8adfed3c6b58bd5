"""jerklab.rig.progress: the rig client's tqdm progress bars.

An ipywidgets bar inside a Jupyter kernel (also a real headless one), text in a terminal,
nothing when disabled, at most ~10 redraws a second with the last count always shown; clean
logs (no redraws when the text goes to a file); and the rig client driving them.
"""

from __future__ import annotations

import io
import sys
import types

import pytest

from jerklab.rig import progress as P

pytest.importorskip("tqdm")


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _plain(s):
    """tqdm.notebook keeps the width with figure spaces (U+2007)."""
    return s.replace("\u2007", " ")


@pytest.fixture
def shown():
    return []


def _run(bar, total, note="complete"):
    for n in range(total + 1):
        bar.update(n)
    bar.close(note)


def test_widget_bar(shown):
    import ipywidgets as W

    bar = P.TqdmProgress(110, "virtual step", widget=True, display=shown.append)
    assert bar.kind == "widget" and shown == [bar.widget]
    box = shown[0]
    label, pbar, text = box.children
    assert isinstance(box, W.HBox) and isinstance(pbar, (W.IntProgress, W.FloatProgress))
    assert _plain(label.value) == "virtual step"
    _run(bar, 110)
    assert pbar.max == 110 and pbar.value == 110 and pbar.bar_style == "success"
    assert _plain(text.value).startswith("110/110 samples, ") and _plain(text.value).endswith(
        " s (complete)"
    )


def test_text_bar_in_a_terminal():
    out = _Terminal()
    bar = P.TqdmProgress(110, "virtual step", stream=out)
    assert bar.kind == "text" and bar.live
    _run(bar, 110)
    last = out.getvalue().split("\r")[-1]
    assert last.startswith("virtual step [" + "#" * 25 + "] 110/110 samples")
    assert last.rstrip().endswith("s complete") and last.endswith("\n")


def test_text_bar_in_a_log_writes_the_start_and_the_end_only():
    log = io.StringIO()  # not a TTY: a CI log, a redirected file
    bar = P.TqdmProgress(1000, "run", stream=log)
    assert not bar.live
    _run(bar, 1000, "timeout")
    text = log.getvalue()
    assert text.count("\r") == 2 and text.count("\n") == 1
    first, last = text.split("\r")[1:]
    assert "] 0/1000 samples" in first
    assert "] 1000/1000 samples" in last and last.rstrip().endswith("s timeout")
    assert "500/1000" not in text


def test_chooser_by_environment(monkeypatch, shown, capsys):
    monkeypatch.setattr(P, "in_jupyter_kernel", lambda: True)
    bar = P.progress(10, "x", display=shown.append)
    assert bar.kind == "widget" and len(shown) == 1
    bar.close("complete")
    monkeypatch.setattr(P, "in_jupyter_kernel", lambda: False)
    out = _Terminal()
    bar = P.progress(10, "x", stream=out)
    assert bar.kind == "text" and bar.live
    assert isinstance(P.progress(10, "x", enabled=False), P.NoProgress)


def test_text_bar_when_ipywidgets_is_missing(monkeypatch, shown):
    import tqdm.notebook

    monkeypatch.setattr(P, "in_jupyter_kernel", lambda: True)
    monkeypatch.setattr(tqdm.notebook, "IProgress", None)  # what tqdm sets without ipywidgets
    out = io.StringIO()
    bar = P.progress(20, "virtual step", display=shown.append, stream=out)
    assert bar.kind == "text" and bar.live  # a kernel shows live text
    _run(bar, 20)
    assert shown == [] and "20/20 samples" in out.getvalue()


def test_no_output_when_disabled(capsys):
    bar = P.progress(10, "x", enabled=False)
    _run(bar, 10)
    assert capsys.readouterr() == ("", "")


def test_kernel_detection(monkeypatch):
    assert P.in_jupyter_kernel() is False  # pytest is no kernel
    fake = types.ModuleType("IPython")
    monkeypatch.setitem(sys.modules, "IPython", fake)
    fake.get_ipython = lambda: None
    assert P.in_jupyter_kernel() is False
    fake.get_ipython = lambda: types.SimpleNamespace()  # terminal IPython
    assert P.in_jupyter_kernel() is False
    fake.get_ipython = lambda: types.SimpleNamespace(kernel=object())
    assert P.in_jupyter_kernel() is True
    monkeypatch.delitem(sys.modules, "IPython")
    assert P.in_jupyter_kernel() is False and "IPython" not in sys.modules


@pytest.mark.parametrize("kind", ["text", "widget"])
def test_at_most_ten_redraws_a_second(kind):
    """A real-time run (1000 samples at 5 ms, 5 s) on a fake clock: <= 10 redraws/s + first + last."""
    now = [0.0]
    clock = lambda: now[0]  # noqa: E731
    if kind == "text":
        bar = P.TqdmProgress(1000, "run", stream=_Terminal(), clock=clock)
    else:
        bar = P.TqdmProgress(1000, "run", widget=True, display=lambda w: None, clock=clock)
    for n in range(1, 1001):
        now[0] += 0.005
        for _ in range(3):  # the client updates after every read
            bar.update(n)
    bar.close("complete")
    assert 45 <= bar.draws <= 5.0 / bar.min_interval + 3
    assert bar._drawn == 1000
    if kind == "text":
        assert bar.stream.getvalue().split("\r")[-1].startswith("run [" + "#" * 25 + "] 1000/1000")
    else:
        assert (
            bar.bar.value == 1000
            and _plain(bar.text.value) == "1000/1000 samples, 5.0 s (complete)"
        )


def test_partial_run_shows_its_last_count():
    now = [0.0]
    bar = P.TqdmProgress(100, "run", widget=True, display=lambda w: None, clock=lambda: now[0])
    bar.update(1)  # the first sample shows at once
    assert bar.bar.value == 1
    bar.update(37)  # within 0.1 s: not drawn yet
    assert bar.bar.value == 1
    bar.close("timeout")
    assert bar.bar.value == 37 and bar.bar.bar_style == "danger"
    assert _plain(bar.text.value).endswith("(timeout)")


def test_drop_in_for_the_rig_client(tmp_path, monkeypatch):
    """The client's calls (update(len(rec)) after each read, close(status)) drive the tqdm bar."""
    from jerklab.rig import client, connect

    out = _Terminal()
    made = []

    def factory(total, label, enabled):
        bar = P.progress(total, label, enabled, stream=out)
        made.append(bar)
        return bar

    monkeypatch.setattr(client, "_progress", factory)
    monkeypatch.setattr(P, "in_jupyter_kernel", lambda: False)
    with connect(recordings=tmp_path) as rig:
        rec = rig.step(2.0, 0.5, rest=0.05)
    assert len(rec) == 110 and len(made) == 1
    last = out.getvalue().split("\r")[-1]
    assert last.startswith(
        "virtual step [" + "#" * 25 + "] 110/110 samples"
    ) and last.rstrip().endswith("complete")


@pytest.mark.notebook
def test_widget_bar_in_a_headless_kernel():
    """A real kernel (nbclient): detected, the tqdm widget is shown, no text bar, execution completes."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_code_cell(
            "from jerklab.rig import progress as P\n"
            "bar = P.progress(50, 'kernel run')\n"
            "for n in range(51):\n"
            "    bar.update(n)\n"
            "bar.close('complete')\n"
            "print('kernel', P.in_jupyter_kernel(), bar.kind, bar.bar.bar_style)"
        )
    ]
    NotebookClient(nb, timeout=60, kernel_name="python3").execute()
    outs = nb.cells[0].outputs
    text = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    views = [
        o
        for o in outs
        if o.output_type == "display_data" and "application/vnd.jupyter.widget-view+json" in o.data
    ]
    assert "kernel True widget success" in text and "samples" not in text
    assert len(views) == 1


def test_rig_client_uses_these_bars(tmp_path, monkeypatch):
    """The client's bars are this module's: a widget for a step inside a kernel, none when disabled."""
    from jerklab.rig import client, connect

    assert client._progress is P.progress and client._NoProgress is P.NoProgress
    shown = []
    monkeypatch.setattr(P, "in_jupyter_kernel", lambda: True)
    monkeypatch.setattr(P, "_display", shown.append)
    with connect(recordings=tmp_path) as rig:
        rec = rig.step(2.0, 0.5, rest=0.05)  # 10 + 100 samples
        assert len(rec) == 110 and len(shown) == 1
        label, pbar, text = shown[0].children
        assert _plain(label.value) == "virtual step"
        assert pbar.max == 110 and pbar.value == 110 and pbar.bar_style == "success"
        rig.step(1.0, 0.1, progress=False)  # disabled: nothing shown
    assert len(shown) == 1


@pytest.mark.notebook
def test_rig_client_in_a_headless_kernel(tmp_path):
    """The rig client in a real kernel (nbclient, as tests/test_notebooks.py): the kernel is
    detected, one widget is shown (no text bar) and the run completes."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_code_cell(
            "from jerklab.rig import connect\n"
            "from jerklab.rig import progress as P\n"
            f"rig = connect(recordings={str(tmp_path)!r})\n"
            "print('kernel', P.in_jupyter_kernel())\n"
            "rec = rig.step(2.0, 0.2)\n"
            "print(len(rec), rec.metadata['status'])\n"
            "rig.close()"
        )
    ]
    NotebookClient(nb, timeout=60, kernel_name="python3").execute()
    outs = nb.cells[0].outputs
    text = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    views = [
        o
        for o in outs
        if o.output_type == "display_data" and "application/vnd.jupyter.widget-view+json" in o.data
    ]
    assert "kernel True" in text and "50 complete" in text and "samples" not in text
    assert len(views) == 1
