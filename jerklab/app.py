"""The standalone tuning page for a class: the pole-placement panel served by Voilà.

Start it from the repository root with::

    .venv/bin/python -m jerklab.app                 # http://127.0.0.1:8866/, virtual rig
    .venv/bin/python -m jerklab.app --public        # listen on every interface (a classroom)
    .venv/bin/python -m jerklab.app --rig simavr    # the firmware on a simulated Uno behind it
    .venv/bin/python -m jerklab.app --rig /dev/ttyACM0   # a real board
    .venv/bin/python -m jerklab.app --rig broker://127.0.0.1:PORT   # a broker already running
    .venv/bin/python -m jerklab.app --pool 4        # keep 4 kernels ready for a class

Voilà runs ``app/tuning.ipynb`` in a fresh kernel for every visitor and shows only its
widgets (no code cells). The page holds :func:`jerklab.widgets.pole_placement_panel` with a
rig behind its "Run this move on the rig" button, a student ID field (every rig run is saved
to ``recordings/<student ID>/``) and a phone-width figure.

Without ``--rig`` every kernel has its own virtual rig. With ``--rig`` (one device for the
whole class), the app starts a :class:`jerklab.broker.RigBroker` that alone opens the rig
and runs the students' moves one at a time, first come first served; the kernels reach it
through ``JERKLAB_RIG_PORT=broker://127.0.0.1:PORT`` and their panels say "queued: 2 ahead
of you" while they wait. ``--rig broker://host:port`` hands the kernels a broker that is
already running (``python -m jerklab.broker``, e.g. one rig shared by two pages) and starts
none. Kernels of pages left idle are shut down (culled) after
``--cull-idle`` seconds.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

from jerklab._validate import as_int
from jerklab.broker import SCHEME, BrokerRig, parse_address
from jerklab.resources import share_path
from jerklab.rig import connect, load_profile
from jerklab.widgets import pole_placement_panel

__all__ = [
    "APP_NOTEBOOK",
    "GUARD",
    "RIG_ENV",
    "CULL_IDLE_S",
    "CULL_INTERVAL_S",
    "panel_for_page",
    "voila_argv",
    "start_broker",
    "main",
]

#: The page Voilà renders (the clone's app/, or its copy in an installed wheel: jerklab.resources).
APP_NOTEBOOK = share_path("app") / "tuning.ipynb"

#: The page's kernel websocket connection: v1 protocol only, malformed frames refused.
GUARD = "jerklab._voila_guard.GuardedKernelConnection"

#: Environment variable carrying ``--rig`` to the page's kernels ("" or unset: virtual rig).
RIG_ENV = "JERKLAB_RIG_PORT"
#: the rig's motor profile (a name or a profile file, jerklab.rig.profiles) for the page's rig
PROFILE_ENV = "JERKLAB_RIG_PROFILE"

#: Default seconds of inactivity after which a page's kernel is shut down, and how often
#: Voilà looks (``MappingKernelManager.cull_idle_timeout`` / ``cull_interval``). A kernel
#: whose page is still open is kept unless ``cull_connected`` (``--cull-connected``).
CULL_IDLE_S = 600
CULL_INTERVAL_S = 60


def panel_for_page(rig_port=None, recordings=None):
    """The widget the page shows: the tuning panel with a rig behind it.

    Parameters
    ----------
    rig_port : str, optional
        ``broker://host:port`` (the app's shared rig, :class:`jerklab.broker.BrokerRig`), or
        anything :func:`jerklab.rig.connect` opens; defaults to ``$JERKLAB_RIG_PORT``, and to
        the virtual rig (``None``) when that is empty.
    recordings : path, optional
        Folder of the per-student folders (default ``$JERKLAB_RECORDINGS`` or ``./recordings``).

    Returns
    -------
    ipywidgets.Widget
        The :class:`jerklab.widgets.PolePlacementPanel` with a student ID field and a phone
        layout; if the rig cannot be reached, the panel without the rig button under a red
        notice saying why (the tuning still works).
    """
    import html

    import ipywidgets as widgets

    if rig_port is None:
        rig_port = os.environ.get(RIG_ENV) or None
    page = dict(student=True, narrow_figure=True, recordings=recordings)
    try:
        if isinstance(rig_port, str) and rig_port.startswith("broker://"):
            rig = BrokerRig(rig_port)
        else:
            rig = connect(rig_port, progress=False, profile=os.environ.get(PROFILE_ENV) or None)
    except Exception as exc:  # the page must still serve the tuning without a rig
        # the kind of failure and the rig the page was given, not the message (it may hold
        # the server's paths)
        where = f" at {rig_port}" if rig_port else ""
        notice = widgets.HTML(
            '<div class="jerklab-rig-missing" style="color:#b71c1c;font-weight:bold">'
            f"No rig behind this page ({html.escape(type(exc).__name__ + where)}); "
            "tuning and simulation only.</div>"
        )
        return widgets.VBox([notice, pole_placement_panel(**page)])
    panel = pole_placement_panel(rig=rig, **page)
    if getattr(rig, "verified", False) and panel.student is not None:
        # on the hub the broker knows who this is: the ID is the hub's, not typed
        panel.student.value = rig.identity
        panel.student.disabled = True
    return panel


def voila_argv(
    port=8866,
    ip="127.0.0.1",
    open_browser=False,
    notebook=APP_NOTEBOOK,
    pool=1,
    extra=(),
    cull_idle=CULL_IDLE_S,
    cull_interval=CULL_INTERVAL_S,
    cull_connected=False,
):
    """Command-line arguments for Voilà serving ``notebook``.

    ``pool`` kernels are kept pre-executed (Voilà's preheat), so a visitor's page shows the
    panel in a few seconds instead of waiting for a kernel to start and run the notebook;
    0 turns it off. Each kernel holds ~0.3 GB.

    A kernel idle for ``cull_idle`` seconds (0: never) is shut down, checked every
    ``cull_interval`` seconds; with ``cull_connected`` also when its page is still open
    (the student walked away), else only once the tab is closed. Voilà never culls the
    pre-executed pool.
    """
    pool = as_int("pool", pool, minimum=0)
    cull_idle = as_int("cull_idle", cull_idle, minimum=0)
    cull_interval = as_int("cull_interval", cull_interval, minimum=1)
    port = as_int("port", port, minimum=1)
    if port > 65535:
        raise ValueError(f"port must be <= 65535, got {port}")
    notebook = pathlib.Path(notebook)
    if not notebook.is_file():
        raise ValueError(f"notebook: {notebook} not found (run from a jerklab source checkout)")
    argv = [
        str(notebook),
        f"--port={port}",
        f"--Voila.ip={ip}",
        "--theme=light",
        # a student's page shows no traceback (they hold the server's paths)
        "--show_tracebacks=False",
        # a kernel websocket without Voila's v1 protocol, or a malformed frame, is refused
        # (they freeze every page of the server: jerklab._voila_guard)
        f"--Voila.kernel_websocket_connection_class={GUARD}",
    ]
    if not open_browser:
        argv.append("--no-browser")
    if pool:
        argv += ["--preheat_kernel=True", f"--pool_size={pool}"]
    if cull_idle:
        argv += [
            f"--MappingKernelManager.cull_idle_timeout={cull_idle}",
            f"--MappingKernelManager.cull_interval={cull_interval}",
            f"--MappingKernelManager.cull_connected={bool(cull_connected)}",
        ]
    return argv + list(extra)


def start_broker(rig, speed=1.0):
    """Start ``python -m jerklab.broker --rig RIG`` and return ``(process, "broker://...")``.

    The broker process alone opens the rig; the page's kernels queue their runs there.
    """
    import subprocess

    proc = subprocess.Popen(
        [sys.executable, "-m", "jerklab.broker", f"--rig={rig}", f"--speed={speed}"],
        stdout=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline().strip()
    if not line.startswith("broker://"):
        proc.wait(10)
        raise RuntimeError(
            f"the rig broker for {rig!r} did not start (exit code {proc.returncode}); "
            "see its message above"
        )
    return proc, line


def main(argv=None):
    """``python -m jerklab.app``: serve the tuning page with Voilà (blocks until Ctrl-C)."""
    ap = argparse.ArgumentParser(
        prog="python -m jerklab.app",
        description="Serve the jerklab pole-placement tuning page (Voilà).",
    )
    ap.add_argument("--port", type=int, default=8866, help="TCP port (default 8866)")
    ap.add_argument("--ip", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    ap.add_argument(
        "--public",
        action="store_true",
        help="listen on every interface (same as --ip 0.0.0.0), for a classroom",
    )
    ap.add_argument(
        "--rig",
        default=None,
        help="rig behind the page: omit for the virtual rig, 'simavr', a serial "
        "device / pyserial URL, or broker://host:port (a running python -m jerklab.broker)",
    )
    ap.add_argument(
        "--pool",
        type=int,
        default=1,
        help="kernels kept pre-executed for the next visitors (default 1, 0: off)",
    )
    ap.add_argument(
        "--rig-speed",
        type=float,
        default=1.0,
        help="--rig virtual only: the shared virtual rig's pace, times real time "
        "(default 1.0, like a board)",
    )
    ap.add_argument(
        "--no-queue",
        action="store_true",
        help="with --rig: let every kernel open the rig itself (one student at a time!)",
    )
    ap.add_argument(
        "--cull-idle",
        type=int,
        default=CULL_IDLE_S,
        help=f"shut down a page's kernel after this many idle seconds (default "
        f"{CULL_IDLE_S}, 0: never)",
    )
    ap.add_argument(
        "--cull-interval",
        type=int,
        default=CULL_INTERVAL_S,
        help=f"seconds between idle checks (default {CULL_INTERVAL_S})",
    )
    ap.add_argument(
        "--cull-connected",
        action="store_true",
        help="also cull idle kernels whose page is still open",
    )
    ap.add_argument(
        "--profile",
        default=None,
        help="the rig's motor: a built-in profile name (jerklab.rig.profiles) or the profile file "
        "written by `jerklab rig check PORT --save FILE` (default: the paper's motor)",
    )
    ap.add_argument("--browser", action="store_true", help="open a web browser")
    args, extra = ap.parse_known_args(argv)
    if args.profile is not None:
        try:
            load_profile(args.profile)
        except (ValueError, TypeError) as exc:
            ap.error(f"--profile: {exc}")
        os.environ[PROFILE_ENV] = str(args.profile)
    ip = "0.0.0.0" if args.public else args.ip
    vargs = voila_argv(
        args.port,
        ip,
        args.browser,
        pool=args.pool,
        extra=extra,
        cull_idle=args.cull_idle,
        cull_interval=args.cull_interval,
        cull_connected=args.cull_connected,
    )
    broker = None
    if args.rig is not None and args.rig.startswith(SCHEME):
        # a broker already running owns the rig: the kernels queue there, none is started
        try:
            parse_address(args.rig)
        except ValueError as exc:
            ap.error(f"--rig: {exc}")
        os.environ[RIG_ENV] = args.rig
    elif args.rig is not None and not args.no_queue:
        broker, address = start_broker(args.rig, speed=args.rig_speed)
        os.environ[RIG_ENV] = address
    elif args.rig is not None:
        os.environ[RIG_ENV] = args.rig
    from voila.app import main as voila_main

    print(
        f"jerklab: serving the tuning page on http://{ip}:{args.port}/ "
        f"(rig: {args.rig or 'virtual, one per kernel'}"
        f"{', runs queued by ' + os.environ[RIG_ENV] if broker else ''}); Ctrl-C stops it",
        flush=True,
    )
    try:
        return voila_main(argv=vargs)
    finally:
        if broker is not None:
            broker.terminate()
            try:
                broker.wait(10)
            except Exception:
                broker.kill()


if __name__ == "__main__":
    sys.exit(main())
