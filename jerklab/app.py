"""The standalone tuning page for a class: the pole-placement panel served by Voilà.

Start it from the repository root with::

    .venv/bin/python -m jerklab.app                 # http://127.0.0.1:8866/, virtual rig
    .venv/bin/python -m jerklab.app --public        # listen on every interface (a classroom)
    .venv/bin/python -m jerklab.app --rig simavr    # the firmware on a simulated Uno behind it
    .venv/bin/python -m jerklab.app --rig /dev/ttyACM0   # a real board
    .venv/bin/python -m jerklab.app --pool 4        # keep 4 kernels ready for a class

Voilà runs ``app/tuning.ipynb`` in a fresh kernel for every visitor and shows only its
widgets (no code cells). The page holds :func:`jerklab.widgets.pole_placement_panel` with
the rig of :func:`jerklab.rig.connect` behind its "Run this move on the rig" button. The rig
port reaches the kernels through the ``JERKLAB_RIG_PORT`` environment variable.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import sys

from jerklab.resources import share_path

__all__ = ["APP_NOTEBOOK", "RIG_ENV", "panel_for_page", "voila_argv", "main"]

#: The page Voilà renders (the clone's app/, or its copy in an installed wheel: jerklab.resources).
APP_NOTEBOOK = share_path("app") / "tuning.ipynb"

#: Environment variable carrying ``--rig`` to the page's kernels ("" or unset: virtual rig).
RIG_ENV = "JERKLAB_RIG_PORT"


def panel_for_page(rig_port=None):
    """The widget the page shows: the tuning panel with a rig behind it.

    Parameters
    ----------
    rig_port : str, optional
        Passed to :func:`jerklab.rig.connect`; defaults to ``$JERKLAB_RIG_PORT``, and to the
        virtual rig (``None``) when that is empty.

    Returns
    -------
    ipywidgets.Widget
        The :class:`jerklab.widgets.PolePlacementPanel`; if the rig cannot be opened, the panel
        without the rig button under a red notice saying why (the tuning still works).
    """
    import ipywidgets as widgets

    from jerklab.widgets import _html_escape, pole_placement_panel

    if rig_port is None:
        rig_port = os.environ.get(RIG_ENV) or None
    try:
        from jerklab.rig import connect

        rig = connect(rig_port, progress=False)
    except Exception as exc:  # the page must still serve the tuning without a rig
        notice = widgets.HTML(
            '<div class="jerklab-rig-missing" style="color:#b71c1c;font-weight:bold">'
            f"No rig behind this page ({_html_escape(f'{type(exc).__name__}: {exc}')}); "
            "tuning and simulation only.</div>")
        return widgets.VBox([notice, pole_placement_panel()])
    return pole_placement_panel(rig=rig)


def voila_argv(port=8866, ip="127.0.0.1", open_browser=False, notebook=APP_NOTEBOOK, pool=1,
               extra=()):
    """Command-line arguments for Voilà serving ``notebook``.

    ``pool`` kernels are kept pre-executed (Voilà's preheat), so a visitor's page shows the
    panel in a few seconds instead of waiting for a kernel to start and run the notebook;
    0 turns it off. Each kernel holds ~0.3 GB.
    """
    from jerklab._validate import as_int

    pool = as_int("pool", pool, minimum=0)
    port = as_int("port", port, minimum=1)
    if port > 65535:
        raise ValueError(f"port must be <= 65535, got {port}")
    notebook = pathlib.Path(notebook)
    if not notebook.is_file():
        raise ValueError(f"notebook: {notebook} not found (run from a jerklab source checkout)")
    argv = [str(notebook), f"--port={port}", f"--Voila.ip={ip}", "--theme=light",
            "--show_tracebacks=True"]
    if not open_browser:
        argv.append("--no-browser")
    if pool:
        argv += ["--preheat_kernel=True", f"--pool_size={pool}"]
    return argv + list(extra)


def main(argv=None):
    """``python -m jerklab.app``: serve the tuning page with Voilà (blocks until Ctrl-C)."""
    ap = argparse.ArgumentParser(prog="python -m jerklab.app",
                                 description="Serve the jerklab pole-placement tuning page (Voilà).")
    ap.add_argument("--port", type=int, default=8866, help="TCP port (default 8866)")
    ap.add_argument("--ip", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    ap.add_argument("--public", action="store_true",
                    help="listen on every interface (same as --ip 0.0.0.0), for a classroom")
    ap.add_argument("--rig", default=None,
                    help="rig behind the page: omit for the virtual rig, 'simavr', or a serial "
                         "device / pyserial URL")
    ap.add_argument("--pool", type=int, default=1,
                    help="kernels kept pre-executed for the next visitors (default 1, 0: off)")
    ap.add_argument("--browser", action="store_true", help="open a web browser")
    args, extra = ap.parse_known_args(argv)
    if args.rig is not None:
        os.environ[RIG_ENV] = args.rig
    ip = "0.0.0.0" if args.public else args.ip
    vargs = voila_argv(args.port, ip, args.browser, pool=args.pool, extra=extra)
    from voila.app import main as voila_main

    print(f"jerklab: serving the tuning page on http://{ip}:{args.port}/ "
          f"(rig: {args.rig or 'virtual'}); Ctrl-C stops it", flush=True)
    return voila_main(argv=vargs)


if __name__ == "__main__":
    sys.exit(main())
