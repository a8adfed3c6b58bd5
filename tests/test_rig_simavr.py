"""The rig client against the real firmware on a simulated Uno (``connect("simavr")``),
and the virtual rig (the Python model of that firmware) against it, sample by sample."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import require_simavr

from jerklab import protocol as P
from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_scurve, plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.rig import Link, RigCommandError, connect

MOTOR = dict(K=27.5, tau=0.034)


@pytest.fixture(scope="module")
def uno(tmp_path_factory):
    require_simavr()
    rec_dir = tmp_path_factory.mktemp("simavr-recordings")
    rig = connect(
        "simavr",
        recordings=rec_dir,
        progress=False,
        device=DCMotor(**MOTOR),
        link=Link(timeout=10.0),
    )
    yield rig
    rig.close()


def test_hello_from_the_firmware(uno):
    assert uno.name == "jerklab-uno" and uno.info.protocol_version == P.PROTOCOL_VERSION
    # the first HELLO right after launch is answered (it used to be lost and only the
    # retry 250 ms later got through); a retry may still be sent if the host is slow
    assert uno.hello_answered == 1
    assert uno.capabilities & P.Capability.PLANNER_SINE_JERK
    assert uno.info.pwm_max == 1023 and uno.info.tick_us == 1000


def test_identify_the_simulated_motor(uno):
    from jerklab.ident import fit_dc_motor

    rec = uno.step(6.0, 0.4)
    assert rec.metadata["status"] == "complete" and len(rec) == 90
    fit = fit_dc_motor(rec.control, rec.position, rec.Ts, method="pem")
    assert fit.K == pytest.approx(MOTOR["K"], rel=0.02)
    assert fit.tau == pytest.approx(MOTOR["tau"], rel=0.05)


def test_firmware_and_virtual_rig_agree(uno, tmp_path):
    """Same move, same gains, same motor: the firmware on simavr and its Python model.

    The gains have a derivative filter (z-domain placement, fourth pole 0.5): with the
    unfiltered derivative of the Stojčić eq. 13 design (37 V/rad per sample) a one-count
    difference in edge timing swings the PWM by ~45 ticks and grew into a two-count difference
    near rest in about one run of three (with or without the computation delay modelled)."""
    from jerklab.controller import discrete_pole_placement_pid

    prof = plan_sine_jerk(4 * math.pi, 2000.0, 300.0, 60.0)
    g = discrete_pole_placement_pid(MOTOR["K"], MOTOR["tau"], 20.0, Ts=0.005, extra_pole=0.5)
    uno.set_model(**MOTOR)
    fw = uno.run_move(prof, g, Ts=0.005, settle=0.2)
    with connect(
        model=(MOTOR["K"], MOTOR["tau"]),
        recordings=tmp_path,
        progress=False,
        device=DCMotor(**MOTOR),
    ) as virt:
        py = virt.run_move(prof, g, Ts=0.005, settle=0.2)
    assert fw.metadata["status"] == "complete" and len(fw) == len(py)
    assert fw.metadata["plan"]["n_samples"] == py.metadata["plan"]["n_samples"]
    assert fw.metadata["device_overruns"] == 0 and fw.metadata["lost_samples"] == 0
    # float32 planner on the AVR vs float64 in Python: the references agree to float32 precision
    assert np.max(np.abs(fw.reference - py.reference)) < 1e-5 * max(1.0, prof.distance)
    # The encoder counts differ by at most a count, when an edge falls next to the sampling
    # instant (interrupt latency on the AVR vs the exact edge time in Python). The control law
    # is the same: the PWM differs only at a sample whose count differs or the one after it
    # (the derivative term) — elsewhere by at most 2 ticks (integrator memory of such a count,
    # float32 round-off). With an integrator on a quantized angle both may hunt by a count at
    # rest (a limit cycle whose phase depends on round-off), so this is checked during the move.
    n = fw.metadata["plan"]["n_samples"]
    dc = fw.counts[:n] != py.counts[:n]
    assert np.max(np.abs(fw.counts[:n] - py.counts[:n])) <= 1
    # at rest: both hold the target within the one-count limit cycle (whose phase differs)
    target = round(prof.distance * uno.counts_per_rad)
    assert (
        np.max(np.abs(fw.counts[n:] - target)) <= 1 and np.max(np.abs(py.counts[n:] - target)) <= 1
    )
    # How many samples may differ: a count differs where an edge falls between the instant the
    # firmware reads the encoder (a few µs after the tick) and the model's t = k Ts, and where the
    # PWM the board writes at the end of its control step (modelled:
    # VirtualDevice.COMPUTE_DELAY, ~0.07 ms with the fixed-point PID)
    # differs in effect from the model's by the step's jitter; the sub-count angle the motor
    # starts at moves the count by a few samples. The differing fraction is about lag * (counts
    # travelled) / (n Ts): bound the timing mismatch it implies. It was bounded by 10 % of Ts
    # when the delay was not modelled (~0.2 ms implied); now by 5 % (~0.17 ms seen).
    travelled = np.sum(np.abs(np.diff(py.counts[:n])))
    implied_lag = dc.sum() * 0.005 / travelled
    assert implied_lag < 0.05 * 0.005, (dc.mean(), implied_lag)
    explained = dc | np.r_[False, dc[:-1]]
    dp = np.abs(fw.pwm[:n] - py.pwm[:n])
    assert np.all(dp[~explained] <= 2), np.flatnonzero(dp > 2)
    # a count through kpd + kdd + kid, in PWM ticks; flips at two consecutive samples enter
    # the derivative twice, so two counts bound the explained differences
    one_count = (g.kpd + g.kdd + g.kid) / uno.counts_per_rad * uno.info.pwm_max / uno.supply_voltage
    assert np.max(dp) <= 2 * one_count + 2
    assert abs(fw.position[-1] - prof.distance) < 2 / uno.counts_per_rad
    assert np.max(np.abs(fw.error)) < 0.05


def test_firmware_refuses_bad_parameters(uno):
    with pytest.raises(RigCommandError, match="'Ts_us'"):
        uno._request(P.SetGains(1.0, 0.0, 0.0, 1500))
    with pytest.raises(RigCommandError, match="'max_voltage'"):
        uno._request(P.SetLimits(1e4, 100.0, 50.0, 30.0, 1000))
    # the default build has no S-curve planner: the host sends the segments (protocol 5)
    assert not uno.capabilities & P.Capability.PLANNER_SCURVE
    assert uno.capabilities & P.Capability.HOST_SEGMENTS
    with pytest.raises(RigCommandError, match="'x0'"):
        uno._request(P.PlanSegment(0, 0, 0.1, float("nan"), 0.0, 0.0, 0.0))
    rec = uno.run_move(
        plan_scurve(1.0, 1e3, 100.0, 10.0), pole_placement_pid(27.5, 0.034, wn=20.0), settle=0.1
    )
    assert rec.metadata["status"] == "complete" and rec.metadata["plan"]["planned_by"] == "host"


@pytest.fixture(scope="module")
def run_1khz(tmp_path_factory):
    """A 4 pi rad sine-jerk move at Ts = 1 ms on the simulated Uno (telemetry at every sample, so
    the sketch is built for 1 Mbaud) and on the virtual rig, and the harness's statistics (the
    default build's D13 probe spans the whole control step)."""
    require_simavr()
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.rig import simavr

    tmp_path = tmp_path_factory.mktemp("rig-1khz")
    build = simavr.firmware_dir() / "build" / "baud1m"
    paths = simavr.build_firmware("avr", build_dir=build, baud=1000000)
    simavr.build_firmware("simavr")
    Ts = 0.001
    prof = plan_sine_jerk(4 * math.pi, 2000.0, 300.0, 60.0)
    # z-domain pole placement with a derivative filter (fourth pole 0.9): at 1 ms an unfiltered
    # derivative turns one count into ~200 PWM ticks
    g = discrete_pole_placement_pid(MOTOR["K"], MOTOR["tau"], 20.0, Ts=Ts, extra_pole=0.9)
    with simavr.launch(paths["elf"], K=MOTOR["K"], tau=MOTOR["tau"], build=False) as uno:
        with connect(
            uno.port, recordings=tmp_path, progress=False, link=Link(timeout=10.0, baudrate=1000000)
        ) as fw_rig:
            fw_rig.set_model(**MOTOR)
            fw = fw_rig.run_move(prof, g, Ts=Ts, settle=0.2)
            cpr = fw_rig.counts_per_rad
        st = uno.stats()
    with connect(
        model=(MOTOR["K"], MOTOR["tau"]),
        recordings=tmp_path,
        progress=False,
        device=DCMotor(**MOTOR),
    ) as virt:
        py = virt.run_move(prof, g, Ts=Ts, settle=0.2)
    return prof, fw, py, st, cpr


def test_1khz_loop_on_the_simulated_uno_matches_the_virtual_rig(run_1khz):
    """A move at Ts = 1 ms on the simulated Uno matches the virtual rig within one count
    at every sample, with no encoder count lost and no overrun (the idle-time preparation keeps
    up: a chunk computed inside a sample counts as an overrun). The whole control step (encoder
    read to PWM write, the next reference, TELEMETRY) leaves at least half of the period for the
    idle-time work; the 4000-cycle ceiling is the next test."""
    prof, fw, py, st, cpr = run_1khz
    assert (
        fw.metadata["status"] == "complete"
        and len(fw) == len(py) == fw.metadata["plan"]["n_samples"] + 200
    )
    assert fw.metadata["device_overruns"] == 0 and fw.metadata["lost_samples"] == 0
    assert np.max(np.abs(fw.reference - py.reference)) < 1e-5 * prof.distance
    assert np.max(np.abs(fw.counts - py.counts)) <= 1  # at every sample
    assert abs(fw.position[-1] - prof.distance) < 2 / cpr
    step = st["control_step_cycles_moving"]
    assert step["n"] >= 0.5 * len(fw) and step["max"] <= 8000, step  # (n: ticks while moving)
    assert st["firmware_counts"] == st["ideal_counts_x1"]
    assert st["int0_latency_cycles"]["over_120"] == 0


def test_1khz_whole_control_step_within_a_quarter_of_the_period(run_1khz):
    """The ceiling of the whole control step (planner sample, feedforward, PID, TELEMETRY;
    interrupts included) <= 4000 cycles, 25 % of 1 ms, at its maximum over the move. Measured
    ~3530 without host bytes in the worst step; a HEARTBEAT's 7 receive interrupts (~52 cycles
    each, the assembly USART_RX ISR) landing there add at most ~370 (the host sends one every
    0.05 s or more), so the bound holds wherever the host's bytes fall."""
    prof, fw, py, st, cpr = run_1khz
    assert st["control_step_cycles_moving"]["max"] <= 4000, st["control_step_cycles_moving"]


def _retarget_on_both(uno, tmp_path, prof, g, Ts, at, new, settle):
    """The move on the simulated Uno, then on the virtual rig, each re-targeted to ``new`` at
    telemetry sample ``at``: the two recordings (firmware, virtual)."""
    recs = []
    uno.set_model(**MOTOR)
    with connect(
        model=(MOTOR["K"], MOTOR["tau"]),
        recordings=tmp_path,
        progress=False,
        device=DCMotor(**MOTOR),
    ) as virt:
        for rig in (uno, virt):

            def cb(k, r, y, rig=rig):
                if k == at:
                    rig.retarget(new)

            recs.append(rig.run_move(prof, g, Ts=Ts, settle=settle, on_telemetry=cb))
    return recs


@pytest.mark.parametrize("kind,at,new", [(1, 10, 25.0), (2, 15, -3.0)])
def test_retarget_on_the_firmware_matches_the_virtual_rig(uno, tmp_path, kind, at, new):
    """RETARGET on the firmware (simavr) during the acceleration phase: the reference
    follows the virtual rig's (the same rule in float64) to float32 precision, stays
    jerk-continuous (no jump in its third differences) and the run ends on the new target."""
    from jerklab.planner import plan_sine_jerk_optimal

    prof = [plan_sine_jerk, plan_sine_jerk_optimal, plan_scurve][kind](
        4 * math.pi, 2000.0, 300.0, 60.0
    )
    g = pole_placement_pid(MOTOR["K"], MOTOR["tau"], wn=20.0).discretize(0.005)
    fw, py = _retarget_on_both(uno, tmp_path, prof, g, 0.005, at, new, settle=0.3)
    assert fw.metadata["status"] == "complete" and fw.metadata["retargets"][0][1] == new
    assert fw.metadata["device_overruns"] == 0 and fw.metadata["lost_samples"] == 0
    assert len(fw) == len(py)
    assert np.max(np.abs(fw.reference - py.reference)) < 1e-5 * 30.0
    assert fw.reference[-1] == pytest.approx(new, abs=1e-5)
    assert abs(fw.position[-1] - new) < 2 / uno.counts_per_rad
    if kind == 1:
        j = np.diff(fw.reference.astype(float), 3) / 0.005**3
        assert np.max(np.abs(np.diff(j))) <= 0.4 * 2000.0
    # and jerklab's float64 reference of the host-planned switches (the ones the board took,
    # replayed: the earliest sample the host asked for, the target); the switch itself is the
    # virtual rig's (the end of the acceleration), the earliest sample asked for need not be
    # (how far the host's telemetry had got when it sent the frames: the machine's load)
    assert _switches(fw) == _switches(py)
    _assert_follows_the_host_plan(fw, prof, kind)


def _switches(rec):
    """The (target, switch sample) of each switch a run took."""
    return [(target, k_s) for _, target, k_s in rec.metadata["retarget_switches"]]


def _assert_follows_the_host_plan(rec, prof, kind, Ts=0.005):
    from jerklab.rig import retarget as RT

    f32 = np.float32
    first = RT.rest_plan(kind, float(f32(prof.distance)), 2000.0, 300.0, 60.0)
    info = rec.metadata["plan"]
    run = RT.RunningPlan(
        first, 0.0, info["accel_time"], info["cruise_time"], info["duration"], kind
    )
    k = np.arange(len(rec.reference))
    want = first.sample(k * Ts)[0]
    for n, (k_e, target, k_s) in enumerate(rec.metadata["retarget_switches"]):
        sw = RT.plan_switch(run, k_e, target, Ts, 2000.0, 300.0, 60.0, base=n)
        assert sw.k_switch == k_s
        want = np.where(k >= k_s, sw.running.plan.sample(k * Ts)[0], want)
        run = sw.running
    assert np.max(np.abs(rec.reference - want)) < 1e-5 * 30.0


@pytest.mark.parametrize(
    "which,at,new",
    [
        ("moving start", 3, 12.0),
        ("overshoot", 3, -1.0),
        ("synchronized", 5, 3.0),
        # a planner's own plan: asked during the move, the switch at rest after its end (its
        # 3-sample segments' chunk changes come while the board prepares the switch: they had
        # found their chunks unprepared, an overrun each), and asked at rest
        ("own", 5, 3.0),
        ("own", 40, 3.0),
    ],
)
def test_retarget_of_a_host_plan_on_the_firmware_matches_the_virtual_rig(
    uno, tmp_path, which, at, new
):
    """RETARGET of a move the host planned itself (no planner's rest-to-rest result: a moving
    start, one that overshoots and comes back, a synchronized profile) on the firmware
    (simavr): the board takes the switch inside PLAN_COMMIT's window, its reference follows
    the virtual rig's and the host's float64 plan of the switch to float32 precision and the
    run ends on the new target, with no overrun."""
    from jerklab import protocol as P
    from jerklab.rig import retarget as RT

    Ts = 0.005
    prof = {
        "moving start": lambda: plan_scurve(8.0, 2e4, 300.0, 30.0, initial_velocity=10.0),
        "overshoot": lambda: plan_scurve(0.5, 2e4, 300.0, 60.0, initial_velocity=40.0),
        "synchronized": lambda: plan_scurve(2.0, 2e4, 300.0, 30.0).synchronized(Ts),
        "own": lambda: plan_scurve(2.0, 2e4, 300.0, 30.0),
    }[which]()
    g = pole_placement_pid(MOTOR["K"], MOTOR["tau"], wn=20.0).discretize(Ts)
    # (a settling of 1 s: the request is taken however far a loaded machine's host lags
    # behind the board's telemetry)
    fw, py = _retarget_on_both(uno, tmp_path, prof, g, Ts, at, new, settle=1.0)
    assert fw.metadata["plan"]["planned_by"] == "host"
    assert fw.metadata["status"] == "complete" and fw.metadata["retargets"][0][1] == new
    assert not fw.metadata.get("retargets_refused"), fw.metadata["retargets_refused"]
    assert fw.metadata["device_overruns"] == 0 and fw.metadata["lost_samples"] == 0
    scale = max(abs(new), 8.0)
    # a switch the plan fixes (the end of an acceleration, the end of the move) is the virtual
    # rig's too; one at the earliest sample the host could make (in a cruise, at rest) depends
    # on how far the host's telemetry has got (the machine's load): the float64 replay below
    # checks it either way
    if all(k_s > k_e for k_e, _, k_s in fw.metadata["retarget_switches"]):
        assert _switches(fw) == _switches(py)
        assert len(fw) == len(py)
        assert np.max(np.abs(fw.reference - py.reference)) < 1e-5 * scale
    assert fw.reference[-1] == pytest.approx(new, abs=1e-5)
    assert abs(fw.position[-1] - new) < 2 / uno.counts_per_rad
    # the host's float64 plan of the switches the board took
    segs, commit = P.profile_segments(prof)
    kind = int(P.Planner[prof.kind.upper()])
    run = RT.host_running_plan(segs, commit, kind)
    k = np.arange(len(fw.reference))
    want = run.plan.sample(k * Ts)[0]
    lim = (2e4, 300.0, prof.max_velocity)
    for n, (k_e, target, k_s) in enumerate(fw.metadata["retarget_switches"]):
        sw = RT.plan_switch(run, k_e, target, Ts, *lim, base=n)
        assert sw.k_switch == k_s
        want = np.where(k >= k_s, sw.running.plan.sample(k * Ts)[0], want)
        run = sw.running
    assert np.max(np.abs(fw.reference - want)) < 1e-5 * scale


def test_late_retarget_on_the_firmware_is_refused_and_retried(uno, monkeypatch):
    """A switch the firmware gets too late (a margin of 2 samples) is refused NACK LATE and
    the host plans it again later: the run ends on the new target, on jerklab's reference."""
    from jerklab.planner import plan_sine_jerk_optimal
    from jerklab.rig import retarget as RT

    real = RT.margin_samples

    def first_late(n_bytes, Ts, baudrate=115200, attempt=0, decimation=1):
        return 2 if attempt == 0 else real(n_bytes, Ts, baudrate, attempt, decimation)

    monkeypatch.setattr(RT, "margin_samples", first_late)
    prof = plan_sine_jerk_optimal(4 * math.pi, 2000.0, 300.0, 60.0)
    g = pole_placement_pid(MOTOR["K"], MOTOR["tau"], wn=20.0).discretize(0.005)
    uno.set_model(**MOTOR)

    def cb(k, r, y):
        if k == 200:  # in the settling (the move ends at sample 137): at once
            uno.retarget(2.0)

    # (a settling of 1 s leaves the retry 0.65 s of run after the request, however far the
    # host's telemetry lags on a loaded machine)
    rec = uno.run_move(prof, g, Ts=0.005, settle=1.0, path=False, on_telemetry=cb)
    assert rec.metadata["status"] == "complete"
    assert len(rec.metadata["retargets_late"]) == 1
    assert rec.reference[-1] == pytest.approx(2.0, abs=1e-5)
    _assert_follows_the_host_plan(rec, prof, 1)


def test_the_deepest_stack_stays_above_the_variables(tmp_path):
    """The firmware's deepest stack, as the harness measures it (the lowest stack pointer of the
    session, interrupts included), stays at least 128 bytes above the end of .bss (issue 28) over
    PLAN with every planner, RUN with a RETARGET, SET_SHAPER, SEQUENCE and STEP. Below that the
    stack would overwrite variables: PLAN's planning (the float planners' calls under the frame
    handler) once reached 55 bytes into .bss, harmless or not only by the link order of the
    variables."""
    import subprocess

    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.planner import plan_sine_jerk_optimal, plan_trapezoid
    from jerklab.rig import simavr
    from jerklab.shaping import input_shaper

    require_simavr()
    paths = simavr.build_firmware("avr")
    simavr.build_firmware("simavr")
    nm = subprocess.run(
        ["avr-nm", str(paths["elf"])], capture_output=True, text=True, check=True
    ).stdout
    bss_end = (
        next(int(ln.split()[0], 16) for ln in nm.splitlines() if ln.endswith(" __bss_end"))
        - 0x800000
    )
    Ts = 0.005
    g = discrete_pole_placement_pid(MOTOR["K"], MOTOR["tau"], 20.0, Ts=Ts, extra_pole=0.5)
    d, J, E, W = 4 * math.pi, 2000.0, 300.0, 60.0
    profiles = [
        plan_sine_jerk(d, J, E, W),
        plan_sine_jerk_optimal(d, J, E, W),
        plan_scurve(d, J, E, W),
        plan_trapezoid(d, E, W),
    ]
    with simavr.launch(paths["elf"], K=MOTOR["K"], tau=MOTOR["tau"], build=False) as sim:
        with connect(sim.port, recordings=tmp_path, progress=False, link=Link(timeout=10.0)) as rig:
            rig.set_model(**MOTOR)
            for prof in profiles:
                assert rig.run_move(prof, g, Ts=Ts, settle=0.05).metadata["status"] == "complete"

            def cb(k, r, y):
                if k == 10:
                    rig.retarget(25.0)

            rec = rig.run_move(profiles[1], g, Ts=Ts, settle=0.05, on_telemetry=cb)
            assert rec.metadata["status"] == "complete" and rec.metadata["retargets"]
            rig.set_shaper(input_shaper("zv", 8.0, 0.05), Ts=Ts)
            assert rig.run_move(profiles[0], g, Ts=Ts, settle=0.05).metadata["status"] == "complete"
            rig.set_shaper(None, Ts=Ts)
            rig.record_prbs(2.0, 0.2, Ts=Ts)
            rig.step(3.0, 0.1)
        st = sim.stats()
    gap = st["stack_min_sp"] + 1 - bss_end
    assert gap >= 128, (
        f"the stack came within {gap} bytes of .bss (lowest SP {st['stack_min_sp']:#x} at "
        f"pc {st['stack_min_pc']:#x}, .bss ends at {bss_end:#x})"
    )


def test_board_planners_build_option_plans_on_the_board_and_agrees_with_the_host(tmp_path):
    """JL_WITH_BOARD_PLANNERS=1 (with JL_WITH_SHAPER=0, to fit) builds the planners 1-3 into the
    board again: the S-curve is then planned by PLAN on the board, and its run's reference is
    the host-planned run's of the default build (both jerklab's profile to float32 precision)."""
    require_simavr()
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.rig import simavr

    build = simavr.firmware_dir() / "build" / "boardplanners"
    paths = simavr.build_firmware(
        "avr",
        "size",
        build_dir=build,
        defines=("-DJL_WITH_BOARD_PLANNERS=1", "-DJL_WITH_SHAPER=0"),
    )
    assert "firmware size:" in paths["output"] and "over the" not in paths["output"]
    default = simavr.build_firmware("avr")
    simavr.build_firmware("simavr")
    Ts = 0.005
    prof = plan_scurve(3.0, 2000.0, 300.0, 60.0)
    g = discrete_pole_placement_pid(MOTOR["K"], MOTOR["tau"], 20.0, Ts=Ts, extra_pole=0.5)
    recs = {}
    for name, elf in (("board", paths["elf"]), ("host", default["elf"])):
        with simavr.launch(elf, K=MOTOR["K"], tau=MOTOR["tau"], build=False) as sim:
            with connect(sim.port, recordings=tmp_path, progress=False) as rig:
                has = bool(rig.capabilities & P.Capability.PLANNER_SCURVE)
                assert has == (name == "board")
                rig.set_model(**MOTOR)
                recs[name] = rig.run_move(prof, g, Ts=Ts, settle=0.1, path=False)
    for name, rec in recs.items():
        assert rec.metadata["status"] == "complete"
        assert rec.metadata["plan"]["planned_by"] == name
        ref = prof.sample(np.asarray(rec.index) * Ts).position
        assert np.max(np.abs(np.asarray(rec.reference) - ref)) <= 2e-5 * 3.0
    assert len(recs["board"]) == len(recs["host"])
