"""``python -m jerklab.rig serve | ports``: serve the virtual rig, or list candidate ports.

``serve`` puts the virtual rig on a pseudo-terminal (or TCP port); it prints the path to open
(``/dev/pts/N`` or ``socket://host:port``) on the first line of stdout, then serves until
Ctrl-C or SIGTERM. ``ports`` lists the serial ports that may have a rig behind them (pyserial's
list_ports), likely Arduinos first, with description, USB VID:PID and who holds each.

    python -m jerklab.rig serve                  # real-time pace, on a pty
    python -m jerklab.rig serve --speed 10       # ten times faster than real time
    python -m jerklab.rig serve --tcp 5000       # socket://127.0.0.1:5000 (the paper's Ethernet set-up)
    python -m jerklab.rig ports                  # which port is the Uno?
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from jerklab import paper
from jerklab.plant import DCMotor
from jerklab.rig.check import main as check_main
from jerklab.rig.ports import list_ports
from jerklab.rig.server import DeviceServer
from jerklab.rig.virtual import VirtualDevice


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["check"]:  # the bring-up check has its own options (jerklab.rig.check)
        return check_main(argv[1:])
    ap = argparse.ArgumentParser(prog="python -m jerklab.rig", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser(
        "check", help="bring-up check of a rig before closing the loop (check PORT --help)"
    )
    s = sub.add_parser("serve", help="serve the virtual rig on a pseudo-terminal or a TCP port")
    s.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="times real time (default 1.0, like a board; 0 = as fast as the host reads)",
    )
    s.add_argument(
        "--tcp",
        type=int,
        metavar="PORT",
        default=None,
        help="listen on this TCP port instead of a pty (0 = any free port)",
    )
    s.add_argument("--host", default="127.0.0.1", help="address to listen on with --tcp")
    s.add_argument(
        "--K",
        type=float,
        default=paper.MOTOR_K,
        help=f"motor gain K, rad/(V s) (default {paper.MOTOR_K:g})",
    )
    s.add_argument(
        "--tau",
        type=float,
        default=paper.MOTOR_TAU,
        help=f"motor time constant tau, s (default {paper.MOTOR_TAU:g})",
    )
    s.add_argument("--friction", type=float, default=0.0, help="Coulomb friction, V (default 0)")
    s.add_argument("--noise", type=float, default=0.0, help="encoder noise std, rad (default 0)")
    pp = sub.add_parser("ports", help="list serial ports that may have a rig behind them")
    pp.add_argument("--all", action="store_true", help="also ports without a USB id (/dev/ttyS*)")
    args = ap.parse_args(argv)
    if args.cmd == "ports":
        return _ports(args.all)
    if args.tcp is None and sys.platform == "win32":
        ap.error(
            "serve on a pseudo-terminal needs Linux or macOS; on Windows use `serve --tcp 5000` "
            "and connect('socket://127.0.0.1:5000'), or the in-process virtual rig: connect()"
        )
    if args.speed < 0:
        ap.error(f"--speed must be >= 0, got {args.speed}")
    motor = DCMotor(K=args.K, tau=args.tau, coulomb_friction=args.friction, noise_std=args.noise)
    server = DeviceServer(VirtualDevice(motor), speed=args.speed or None)
    port = server.start_tcp(args.host, args.tcp) if args.tcp is not None else server.start_pty()
    print(port, flush=True)
    print(
        f"jerklab virtual rig (K={args.K}, tau={args.tau}, speed={args.speed or 'max'}) on {port}; "
        "Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: done.set())
    try:
        while not done.wait(0.2):
            if server.error is not None:
                print(f"server stopped: {server.error!r}", file=sys.stderr)
                return 1
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


def _ports(include_all=False) -> int:
    rows = list_ports(include_all=include_all)
    if not rows:
        print(
            "no USB serial port found: plug the Uno in (a charge-only cable shows nothing); "
            "--all lists ports without a USB id"
        )
        return 1
    print(f"{'port':24s} {'VID:PID':9s} {'likely':10s} description")
    for r in rows:
        mark = "*" if r["likely"] == "arduino" else " "
        extra = "; ".join(
            x for x in (r["note"], f"in use by {r['holder']}" if r["holder"] else "") if x
        )
        print(
            f"{mark}{r['device']:23s} {r['vid_pid'] or '-':9s} {r['likely'] or '-':10s} "
            f"{r['description']}" + (f" [{extra}]" if extra else "")
        )
    print(
        "* likely an Arduino. Connect with jerklab.rig.connect(PORT); flash with the Arduino "
        "IDE (firmware/jerklab_rig/jerklab_rig.ino, docs/RIG.md) or make -C firmware upload PORT=PORT"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
