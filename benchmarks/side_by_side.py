"""Old and new jerklab timed side by side in one process (interleaved), for "nothing got slower".

``python -m benchmarks.side_by_side OLD_TREE [--out PATH]``

``OLD_TREE`` is a checkout of an earlier commit (e.g. ``git worktree add /tmp/old <commit>``
or ``git archive <commit> | tar -x -C /tmp/old``). Its ``jerklab`` package is imported under
its own module objects next to the current one, and every case below runs on both,
interleaved, repeated, the best time kept: a loaded machine slows both alike. The ratio is
old/new (> 1: the new code is faster). ``--out`` writes the table as a JSON record (the
format of ``python -m benchmarks``).
"""

from __future__ import annotations

import importlib
import json
import pathlib
import sys
import time

import numpy as np

from benchmarks import _record

MODULES = (
    "jerklab",
    "jerklab.law",
    "jerklab.controller",
    "jerklab.planner",
    "jerklab.plant",
    "jerklab.sim",
    "jerklab.ident",
    "jerklab.piezo",
    "jerklab.widgets",
)


def load_tree(root):
    """Import ``jerklab`` from ``root`` as separate module objects (returned as a dict by name)."""
    root = str(pathlib.Path(root).resolve())
    saved = {k: v for k, v in sys.modules.items() if k == "jerklab" or k.startswith("jerklab.")}
    for k in saved:
        del sys.modules[k]
    sys.path.insert(0, root)
    try:
        mods = {}
        for name in MODULES:
            try:
                mods[name] = importlib.import_module(name)
            except ImportError:
                mods[name] = None
        loaded = {
            k: v for k, v in sys.modules.items() if k == "jerklab" or k.startswith("jerklab.")
        }
    finally:
        sys.path.remove(root)
        for k in loaded:
            del sys.modules[k]
        sys.modules.update(saved)
    if not mods["jerklab"].__file__.startswith(root):
        raise RuntimeError(f"{root} did not provide jerklab (got {mods['jerklab'].__file__})")
    return mods


def _cases(J):
    """name -> callable running the case with the modules ``J``."""
    ctl, planner, plant, sim = (
        J["jerklab.controller"],
        J["jerklab.planner"],
        J["jerklab.plant"],
        J["jerklab.sim"],
    )
    K, TAU, TS = 32.4, 0.025, 0.005
    d = ctl.discrete_pole_placement_pid(K, TAU, 30.0, Ts=TS)
    c = ctl.DigitalController(d, ctl.Feedforward(K, TAU), output_limit=12.0)
    motor = plant.DCMotor(coulomb_friction=0.3, load_disturbance=(1.0, -0.5))
    prof = planner.plan_sine_jerk(10.0, 2e4, 300.0, 100.0)
    pp = sim.perturbed_plants(2000, friction=(0.0, 0.5), seed=1)
    dists = iter(np.linspace(9.0, 11.0, 10**7))
    rng = np.random.default_rng(0)
    cases = {
        "simulate 401 samples (same move)": lambda: sim.simulate(prof, motor, c, t_end=2.0),
        "simulate 401 samples (new move each call)": lambda: sim.simulate(
            planner.plan_sine_jerk(next(dists), 2e4, 300.0, 100.0), motor, c, t_end=2.0
        ),
        "simulate 4001 samples": lambda: sim.simulate(prof, motor, c, t_end=20.0),
        "simulate_batch compiled 2000 plants": lambda: sim.simulate_batch(
            prof, motor, c, keep_traces=False, **pp
        ),
        "simulate_batch numpy 500 plants": lambda: sim.simulate_batch(
            prof, motor, c, engine="numpy", keep_traces=False, **{k: v[:500] for k, v in pp.items()}
        ),
        "DigitalController.step x1000": lambda: [
            c.step(0.1 * k, 1.0, 0.0, 0.1 * k - 0.01) for k in range(1000)
        ],
        "plan_sine_jerk x1000": lambda: [
            planner.plan_sine_jerk(1.0 + k, 2e4, 300.0, 100.0) for k in range(1000)
        ],
        "plan_batch sine_jerk 1e5": lambda: planner.plan_batch(
            "sine_jerk", rng.uniform(0.1, 10, 100000), 2e4, 300.0, 100.0
        ),
        "PositionLoop redraw set": lambda: [
            (L.poles_z(), L.step_response(0.5), L.disturbance_response(0.5), L.tracking_error(prof))
            for L in (
                ctl.PositionLoop(K, TAU, ctl.pole_placement_pid(K, TAU, 30.0).discretize(TS)),
                ctl.PositionLoop(K, TAU, d),
            )
        ],
    }
    ident = J.get("jerklab.ident")
    if ident is not None:
        u = ident.prbs(2.0, TS, 3.0, offset=6.0)
        th, _ = plant.DCMotor(supply_voltage=12.0).open_loop(u, TS)
        cases["fit_dc_motor pem 2 s"] = lambda: ident.fit_dc_motor(u, th[:-1], TS)
        recs = {}
        for dur in (0.5, 8.0):
            ud = ident.prbs(dur, TS, 3.0, offset=6.0, clock_period=0.02, seed=1)
            recs[dur] = (ud, plant.DCMotor(noise_std=0.002, seed=1).open_loop(ud, TS)[1][:-1])
        for dur, (ud, yd) in recs.items():
            cases[f"fit_dc_motor pem {dur:g} s, 2 mrad"] = lambda ud=ud, yd=yd: ident.fit_dc_motor(
                ud, yd, TS
            )
        uf = ident.prbs(8.0, TS, 4.0, clock_period=0.04, seed=3)
        yf = plant.DCMotor(coulomb_friction=0.4, offset=0.2, noise_std=0.001, seed=3).open_loop(
            uf, TS
        )[1][:-1]
        cases["fit_dc_motor pem friction+offset+delay 8 s"] = lambda: ident.fit_dc_motor(
            uf, yf, TS, friction=True, offset=True, delay=True
        )
    widgets = J.get("jerklab.widgets")
    if widgets is not None and hasattr(widgets, "compute_pole_placement"):
        ws = iter(np.linspace(20.0, 40.0, 10**6))
        cases["compute_pole_placement (panel math)"] = lambda: widgets.compute_pole_placement(
            wn=next(ws)
        )
    pz = J.get("jerklab.piezo")
    if pz is not None:
        cases["piezo shape_cycle(1, 2) default solver"] = lambda: pz.shape_cycle(1, 2)
    return cases


def main(argv):
    if not argv or argv[0].startswith("-"):
        print(__doc__)
        return 2
    old_root = argv[0]
    out = argv[argv.index("--out") + 1] if "--out" in argv else None
    repeat = int(argv[argv.index("--repeat") + 1]) if "--repeat" in argv else 7
    old = load_tree(old_root)
    new = {name: importlib.import_module(name) for name in MODULES}
    co, cn = _cases(old), _cases(new)
    rows = []
    for name in cn:
        if name not in co:
            continue
        fo, fn = co[name], cn[name]
        fo(), fn()  # compile / warm caches
        n = 1
        t0 = time.perf_counter()
        fn()
        one = time.perf_counter() - t0
        n = max(1, int(0.1 / max(one, 1e-7)))  # ~0.1 s per timing
        best = {"old": np.inf, "new": np.inf}
        for _ in range(repeat):
            for tag, f in (("old", fo), ("new", fn)):
                t0 = time.perf_counter()
                for _ in range(n):
                    f()
                best[tag] = min(best[tag], (time.perf_counter() - t0) / n)
        rows.append((name, best["old"] * 1e3, best["new"] * 1e3, best["old"] / best["new"]))
    title = "old vs new jerklab, interleaved in one process (best of %d)" % repeat
    _record.CURRENT["module"] = "benchmarks.side_by_side"
    _record.table(
        title,
        ["case", "old ms", "new ms", "old/new"],
        rows,
        note=f"old: {old['jerklab'].__file__}\nnew: {new['jerklab'].__file__}",
    )
    if out:
        from benchmarks.__main__ import _git, _machine, _versions

        rec = {
            "date": time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime()),
            "machine": _machine(),
            "versions": _versions(),
            "git": _git(pathlib.Path(new["jerklab"].__file__).parent.parent),
            "old_tree": str(old_root),
            "modules": {"benchmarks.side_by_side": {"tables": list(_record.TABLES)}},
        }
        pathlib.Path(out).write_text(json.dumps(rec, indent=1, ensure_ascii=False) + "\n")
        print(f"record written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
