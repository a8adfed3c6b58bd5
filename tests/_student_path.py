"""The student's path, run by tests/test_portability.py and tests/test_packaging.py in a subprocess.

    python _student_path.py WORKDIR [--block-posix]

With ``--block-posix`` a meta-path finder refuses ``pty``, ``tty``, ``termios`` and ``fcntl`` to
any importer from jerklab (pyserial and the standard library keep theirs), and the second half
runs with ``sys.platform`` set to "win32" to check the Windows messages of ``serve`` and
``"simavr"``. Prints one ``step: ...`` line per step and ``STUDENT PATH OK`` at the end.
"""

import os
import sys

BLOCKED = {"pty", "tty", "termios", "fcntl"}
refused = []


class BlockPosix:
    """Refuse the POSIX-only modules to jerklab's code (the first importing frame outside importlib)."""

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] not in BLOCKED:
            return None
        f = sys._getframe(1)
        while f is not None and (
            "importlib" in f.f_code.co_filename or f.f_code.co_filename.startswith("<frozen")
        ):
            f = f.f_back
        importer = f.f_globals.get("__name__", "") if f is not None else ""
        if importer.split(".")[0] == "jerklab":
            refused.append((importer, name))
            raise ImportError(f"{name} is blocked: not on Windows (imported by {importer})")
        return None


def main():
    work = os.path.abspath(sys.argv[1])
    block = "--block-posix" in sys.argv
    if block:
        for m in BLOCKED:
            assert m not in sys.modules, f"{m} already imported at start-up"
        sys.meta_path.insert(0, BlockPosix())
        # the blocker works: a jerklab-named module that imports tty fails
        probe = {"__name__": "jerklab._probe"}
        try:
            exec("import tty", probe)
        except ImportError:
            pass
        else:
            raise AssertionError("the import blocker let tty through")
        refused.clear()

    # jerklab[lab] does not install otter-grader: the student path must not need it
    sys.modules["otter"] = None

    import jerklab
    from jerklab import cli, ident
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.planner import plan_sine_jerk
    from jerklab.rig import Link, UnknownPortError, connect
    from jerklab.rig.check import check_rig
    from jerklab.rig.server import DeviceServer

    print("step: import", jerklab.__version__, jerklab.__file__)

    assert cli.main(["lab", os.path.join(work, "lab"), "--copy-only"]) == 0
    assert os.path.isfile(os.path.join(work, "lab", "notebooks", "05_live_rig.ipynb"))
    print("step: jerklab lab --copy-only")

    rig = connect(progress=False, recordings=os.path.join(work, "recordings"))
    gains = discrete_pole_placement_pid(32.4, 0.025, wn=20.0, zeta=1.0, Ts=0.005)
    rec = rig.run_move(plan_sine_jerk(3.0, 2e4, 300.0, 100.0), gains, Ts=0.005)
    step = rig.step(6.0, 0.3, Ts=0.005)
    assert os.path.commonpath([work, str(rec.csv_path.resolve())]) == work
    print("step: virtual rig move ->", rec.csv_path.name, "and", step.csv_path.name)
    fit = ident.IdentData.from_recording(step).fit("arx")
    print("step: identification K =", round(float(fit.K), 2))
    found = check_rig(rig)
    assert all(f.ok for f in found), [str(f) for f in found]
    rig.close()
    print("step: rig check")

    from jerklab.app import panel_for_page
    from jerklab.widgets import pole_placement_panel

    pole_placement_panel()
    panel_for_page()
    print("step: panel and class page")

    # a worksheet's check cell, from the copied worksheet, in an environment without otter-grader
    from jerklab import lab
    from jerklab.lab.notebook import Notebook

    grader = Notebook(os.path.join(work, "lab", "notebooks", "labs", "lab1_identify.ipynb"))
    S = lab.start(1, student="s7", port=None)
    outcome = grader.check("pre_speed", {"S": S, "pre_speed": ...})
    assert not outcome.passed and "`...`" in outcome.message, outcome
    print("step: worksheet check ->", outcome)

    try:
        connect("COM7", progress=False, link=Link(hello_timeout=0.2))
    except UnknownPortError as exc:
        assert "COM7" in str(exc)
    else:
        raise AssertionError("COM7 opened")
    server = DeviceServer(speed=None)
    url = server.start_tcp("127.0.0.1", 0)
    with connect(
        url,
        progress=False,
        recordings=os.path.join(work, "recordings"),
        link=Link(hello_timeout=3.0),
    ) as net:
        assert len(net.step(3.0, 0.1, Ts=0.005, rest=0.0, path=False)) == 20
    server.close()
    print("step: COM port message and the rig over TCP (serve --tcp)")

    if block:
        assert not refused, refused
        import io
        from contextlib import redirect_stderr

        import jerklab.rig.__main__ as rig_main

        real = sys.platform
        sys.platform = "win32"
        try:
            err = io.StringIO()
            with redirect_stderr(err):
                try:
                    rig_main.main(["serve"])
                except SystemExit as e:
                    assert e.code == 2
            assert "--tcp" in err.getvalue() and "virtual rig" in err.getvalue(), err.getvalue()
            try:
                connect("simavr", progress=False)
            except UnknownPortError as exc:
                assert "virtual rig" in str(exc) and "Linux or macOS" in str(exc), exc
            else:
                raise AssertionError("simavr started on 'win32'")
            openpty = os.__dict__.pop("openpty", None)
            try:
                DeviceServer().start_pty()
            except OSError as exc:
                assert "start_tcp" in str(exc), exc
            else:
                raise AssertionError("a pty on 'win32'")
            finally:
                if openpty is not None:
                    os.openpty = openpty
        finally:
            sys.platform = real
        print("step: Windows messages of serve and simavr")
        assert not refused, refused
        leaked = BLOCKED & set(sys.modules)
        # pyserial (serialposix) may hold termios/fcntl on this POSIX host: only it may
        print("step: POSIX modules loaded by others:", sorted(leaked))
    print("STUDENT PATH OK")


if __name__ == "__main__":
    main()
