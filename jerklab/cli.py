"""The ``jerklab`` command (installed by pip on every OS; ``python -m jerklab`` is the same).

Commands::

    jerklab lab [FOLDER]         copy the notebooks, worksheets and data into your working folder
                                 (first use; your edits are never overwritten), open JupyterLab there
    jerklab app [...]            the class page (the tuning panel served by Voilà): python -m jerklab.app
    jerklab rig ports            which serial port is the Uno?
    jerklab rig check PORT       bring-up check of a rig before closing the loop
    jerklab rig serve [--tcp N]  the virtual rig on a pseudo-terminal (Linux, macOS) or a TCP port
    jerklab --version
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from jerklab import __version__
from jerklab.resources import copy_missing, default_work_dir

__all__ = ["main"]

_LAB_HINT = 'JupyterLab is not installed: pip install "jerklab[lab]"'


def lab(argv=None) -> int:
    """``jerklab lab``: fill the working folder (missing files only) and open JupyterLab there."""
    ap = argparse.ArgumentParser(
        prog="jerklab lab", description=lab.__doc__.split(":", 1)[1].strip()
    )
    ap.add_argument(
        "folder",
        nargs="?",
        default=None,
        help="working folder (default $JERKLAB_HOME or ~/jerklab)",
    )
    ap.add_argument(
        "--no-copy",
        action="store_true",
        help="open FOLDER as it is, copy nothing (developers: make lab opens notebooks/)",
    )
    ap.add_argument(
        "--copy-only", action="store_true", help="copy the files, do not start JupyterLab"
    )
    ap.add_argument("--no-browser", action="store_true", help="do not open a web browser")
    ap.add_argument(
        "--port", type=int, default=None, help="JupyterLab's port (default 8888 or the next free)"
    )
    ap.epilog = "Other JupyterLab options after --, e.g. jerklab lab -- --ServerApp.ip=0.0.0.0"
    argv = list(sys.argv[1:] if argv is None else argv)
    cut = argv.index("--") if "--" in argv else len(argv)
    args, extra = ap.parse_args(argv[:cut]), argv[cut + 1 :]
    work = Path(args.folder).expanduser() if args.folder else default_work_dir()
    if not args.no_copy:
        copied, kept = copy_missing(work)
        print(f"jerklab: working folder {work.resolve()}")
        print(f"  copied {len(copied)} file(s); kept {len(kept)} already there (never overwritten)")
        for p in kept[:8]:
            print(f"    kept {p}")
        if len(kept) > 8:
            print(f"    ... and {len(kept) - 8} more")
        if kept:
            print("  (delete a file to get a fresh copy of it at the next `jerklab lab`)")
    elif not work.is_dir():
        print(f"jerklab lab: no folder {work}", file=sys.stderr)
        return 2
    cmd = [sys.executable, "-m", "jupyterlab", str(work)]
    if args.no_browser:
        cmd.append("--no-browser")
    if args.port is not None:
        cmd.append(f"--port={args.port}")
    if getattr(os, "geteuid", lambda: 1)() == 0:  # root in a container (POSIX only)
        cmd.append("--allow-root")
    cmd += extra
    if args.copy_only:
        print("  to open it: " + " ".join(cmd))
        return 0
    try:
        import jupyterlab  # noqa: F401
    except ImportError:
        print(f"jerklab lab: {_LAB_HINT}", file=sys.stderr)
        return 1
    proc = subprocess.Popen(cmd)
    while True:
        try:
            return proc.wait()
        except KeyboardInterrupt:  # JupyterLab has the same Ctrl-C and asks before it stops
            continue


def app(argv=None) -> int:
    """``jerklab app``: the class page; arguments as ``python -m jerklab.app --help``."""
    try:
        import voila  # noqa: F401
    except ImportError:
        print('jerklab app: Voilà is not installed: pip install "jerklab[lab]"', file=sys.stderr)
        return 1
    from jerklab.app import main as app_main  # the subcommand's modules only (the rig: ~1 s)

    # the page's rig runs go to the working folder, never inside the installed package
    os.environ.setdefault("JERKLAB_RECORDINGS", str(default_work_dir() / "recordings"))
    return app_main(argv) or 0


def rig(argv=None) -> int:
    """``jerklab rig ports|check|serve``: as ``python -m jerklab.rig``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["check"]:
        from jerklab.rig.check import main as check_main

        return check_main(argv[1:], prog="jerklab rig check")
    from jerklab.rig.__main__ import main as rig_main

    return rig_main(argv) or 0


_COMMANDS = {"lab": lab, "app": app, "rig": rig}


def main(argv=None) -> int:
    """Entry point of the ``jerklab`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(
        prog="jerklab",
        description=__doc__.split("\n")[0],
        epilog=textwrap.dedent("\n".join(__doc__.split("\n")[4:])),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--version", action="version", version=f"jerklab {__version__}")
    ap.add_argument("command", choices=sorted(_COMMANDS), help="what to do")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="the command's own arguments")
    if argv and argv[0] in _COMMANDS:
        return _COMMANDS[argv[0]](argv[1:])
    args = ap.parse_args(argv)  # --version, --help, or an error naming the choices
    return _COMMANDS[args.command](args.args)


if __name__ == "__main__":
    sys.exit(main())
