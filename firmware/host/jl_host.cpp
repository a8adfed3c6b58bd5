// Host driver for the firmware's portable core (compiled with g++, float32 arithmetic as on
// the AVR). Two modes, both used by tests/test_firmware.py:
//
//   jl_host vectors FILE   check golden vectors written by jerklab (planner phase times,
//                          closed-form samples, the control-loop stepper, controller steps,
//                          frame encoding/decoding); prints one summary line per kind with the
//                          worst error and exits 1 if any record is outside its tolerance.
//   jl_host device [K tau supply [encoder]]
//                          run the device state machine (jerklab_rig/src/jl_device) against a simulated
//                          motor (exact ZOH DC motor, Stojčić eq. 1) driven by a script on stdin:
//                            rx HEX    bytes arriving from the host now
//                            ms N      let N milliseconds (1 ms timer ticks) pass
//                            quit
//                          and print what the device does: "tx MS HEX" (a frame sent),
//                          "pwm MS VALUE" (output changed). encoder: 1 wired as
//                          specified (default), -1 reversed (A and B swapped), 0 disconnected.
//
// Vector records (one per line, whitespace separated; '#' starts a comment):
//   P d J E W  T tv tu               published plan: phase times
//   S d J E W t  j a v x             closed-form sample at t
//   K d J E W Ts n                   control-loop stepper; n lines "s j a v x" for k = 0..n-1
//   G shape nseg target sj sa sv sx w Ts n
//                                    host-planned segments (PLAN_SEGMENT, version 5): nseg
//                                    lines "g kind duration x0 v0 a0 jerk", then the stepper
//                                    as K (n lines "s j a v x"); sj..sx the scales, w the
//                                    largest pulse frequency
//   C kpd kid kdd gamma limit K tau ff loop Ts
//                                    controller reset; ff = 1 adds the feedforward,
//                                    loop 0 position / 1 velocity
//   c r v a y  u p i d uf sat        one controller step
//   F type seq PAYLOADHEX FRAMEHEX   encode check (PAYLOADHEX '-' = empty)
//   D STREAMHEX nframes dropped      decode a byte stream; then nframes lines
//                                    "f type seq PAYLOADHEX" with the frames expected in order
//   H n A0..A9 d0..d9 N              SET_SHAPER's fixed-point FIR (jl::Shaper; A the float32
//                                    amplitudes' bits in hex); then N lines "h R Rs v a": the
//                                    Q32.32 reference in, the shaped one, its Q16.16 velocity
//                                    and acceleration out (jerklab.rig.virtual.FixedShaper:
//                                    bit for bit)
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "jl_control.h"
#include "jl_crc.h"
#include "jl_device.h"
#include "jl_fixed.h"
#include "jl_frame.h"
#include "jl_planner.h"

namespace {

std::vector<uint8_t> from_hex(const std::string& s) {
    std::vector<uint8_t> out;
    if (s == "-") return out;
    for (size_t i = 0; i + 1 < s.size(); i += 2) out.push_back(static_cast<uint8_t>(std::stoul(s.substr(i, 2), nullptr, 16)));
    return out;
}

std::string to_hex(const uint8_t* p, size_t n) {
    static const char* d = "0123456789abcdef";
    std::string s;
    for (size_t i = 0; i < n; ++i) { s += d[p[i] >> 4]; s += d[p[i] & 15]; }
    return s.empty() ? "-" : s;
}

struct Stat {
    explicit Stat(const char* n) : name(n) {}
    const char* name;
    long records = 0, failures = 0;
    double worst = 0.0;   // worst error / tolerance
    std::string worst_what;
    void check(double err, double tol, const std::string& what) {
        ++records;
        double r = tol > 0 ? err / tol : (err > 0 ? 1e300 : 0.0);
        if (!(r <= 1.0)) {
            if (failures < 10) std::fprintf(stderr, "%s mismatch: %s (error %.3g > tol %.3g)\n", name, what.c_str(), err, tol);
            ++failures;
        }
        if (r > worst || std::isnan(r)) { worst = r; worst_what = what; }
    }
};

// Tolerances (float32 arithmetic against float64 jerklab), relative to each quantity's scale.
const double kRtolPlan = 2e-6 * 8;      // phase times: a few float32 ulps through cbrt/sqrt
const double kRtolSample = 1e-5;        // closed form: ~ 100 float32 eps of the scale
const double kRtolStepper = 5e-5;       // rotation recurrence drifts ~ eps per step
const double kRtolControl = 2e-5;       // of the output limit / gains x signal scale

static std::string wh0(const char* path, long lineno, long k) {
    std::ostringstream w;
    w << path << ":" << lineno << " k=" << k;
    return w.str();
}

int run_vectors(const char* path) {
    std::ifstream in(path);
    if (!in) { std::fprintf(stderr, "cannot open %s\n", path); return 2; }
    Stat plan("plan"), smp("sample"), stp("stepper"), ctl("controller"), ctlq("controller_fixed"), enc("encode"), dec("decode");
    Stat pulse("pulse");         // the pulses' integer sinusoids (recurrence, eps, range)
    Stat shp("shaper");          // the fixed-point FIR against its Python twin, exactly
    Stat hstp("host_segments");  // the stepper on host-planned segments (G records)
    Stat root("cube_root");      // the planners' cube root against the true one, in ulp (R records)
    jl::Pid pid;
    jl::PidQ pidq;               // the fixed-point law, in "counts" and "ticks" (scales below)
    double q_se = 1.0, q_su = 1.0, q_kabs = 0.0, q_kid = 0.0, q_acc = 0.0, q_gamma = 0.0, q_emax = 0.0;
    jl::Feedforward ff;
    bool use_ff = false, velocity_loop = false, first = true;
    float ctl_Ts = 0.005f, y_prev = 0.0f;
    double ctl_scale = 1.0;
    std::string line;
    long lineno = 0;
    while (std::getline(in, line)) {
        ++lineno;
        if (line.empty() || line[0] == '#') continue;
        std::istringstream ss(line);
        std::string kind;
        ss >> kind;
        std::ostringstream where;
        where << path << ":" << lineno;
        if (kind == "P" || kind == "S" || kind == "K" || kind == "G") {
            jl::Plan p;
            double sj, sa, sv, sx, w;
            int shape;                   // PulseShape (the jump allowances)
            const bool host_seg = kind == "G";
            if (host_seg) {
                // host-planned segments (protocol version 5): the plan as PLAN_SEGMENTs and
                // PLAN_COMMIT build it (jl::HostPlanner, every one accepted), then the stepper
                // as for K; the scales (jerk, accel, velocity, distance) and the largest pulse
                // frequency come from jerklab, the pulse shape for the jump allowances
                int nseg;
                double target;
                ss >> shape >> nseg >> target >> sj >> sa >> sv >> sx >> w;
                jl::HostPlanner hp = {0};
                bool ok = true;
                for (int i = 0; i < nseg; ++i) {
                    if (!std::getline(in, line)) { plan.check(1, 0, "truncated segment block"); ok = false; break; }
                    ++lineno;
                    std::istringstream ls(line);
                    std::string tag;
                    int sk;
                    double du, x0, v0, a0, jk;
                    ls >> tag >> sk >> du >> x0 >> v0 >> a0 >> jk;
                    if (!ok) continue;    // (after a refused segment: the block's lines only)
                    const jl::HostSegment hs = {(uint8_t)i, (uint8_t)sk, (float)du, (float)x0, (float)v0, (float)a0, (float)jk};
                    const uint8_t bad = hp.add(&p, hs);
                    plan.check(bad != 0xFF, 0.5, where.str() + " segment " + std::to_string(i) + " refused, field " + std::to_string(bad));
                    if (bad != 0xFF) ok = false;
                }
                const jl::HostCommit hc = {(uint8_t)nseg, (float)target, 0.0f, 0.0f, 0.0f, jl::kPlannerHost};
                const uint8_t bad = ok ? hp.check(hc) : 0;
                if (ok) plan.check(bad != 0xFF, 0.5, where.str() + " commit refused, field " + std::to_string(bad));
                if (bad != 0xFF) {
                    // (refused: skip the block's samples)
                    double Ts;
                    long n;
                    ss >> Ts >> n;
                    for (long k = 0; k < n && std::getline(in, line); ++k) ++lineno;
                    continue;
                }
                hp.commit(&p, hc);
                kind = "K";
            } else {
                int pk;
                double d, J, E, W;
                ss >> pk >> d >> J >> E >> W;
                // (every planner of the source, whether the board build has it or not:
                // JL_WITH_BOARD_PLANNERS)
                int st = pk == 0 ? jl::plan_sine_jerk((float)d, (float)J, (float)E, (float)W, &p)
                         : pk == 1 ? jl::plan_sine_jerk_optimal((float)d, (float)J, (float)E, (float)W, &p)
                         : pk == 2 ? jl::plan_scurve((float)d, (float)J, (float)E, (float)W, &p)
                                   : jl::plan_trapezoid((float)d, (float)E, (float)W, &p);
                if (st != jl::kPlanOk) { plan.check(1, 0, where.str() + " plan refused"); continue; }
                // scales: jerk parameter, peak acceleration, peak velocity, distance
                // (the planner's jpar and pulse time tj: the rising pulse's end, the second
                // segment's start)
                shape = pk <= 1 ? jl::kShapeSine : (pk == 2 ? jl::kShapeLinear : jl::kShapeStep);
                const double jpar = pk == 3 ? (float)E : (float)J;
                const double tj = shape != jl::kShapeStep && p.nseg > 1 ? p.seg[1].t0 : 0.0;
                double apk = shape == jl::kShapeSine ? 2.0 / M_PI * jpar * tj
                             : (shape == jl::kShapeLinear ? jpar * tj : jpar);
                sj = shape == jl::kShapeStep ? 0.0 : J;
                sa = apk;
                sv = p.cruise_velocity;
                sx = std::fabs(d);
                w = tj > 0 ? M_PI / tj : 0.0;
            }
            // float32 time: t (and the phase boundaries) carry ~eps * t of rounding, which shifts
            // a short jerk pulse late in a long move; the tolerance allows for that shift
            // (derivative of each quantity times the time error) on top of the relative one.
            auto tol = [&](double rtol, double scale, double deriv, double t, double teps) {
                return rtol * scale + deriv * teps * 6e-8 * std::max(std::fabs(t), (double)p.duration);
            };
            // a trapezoid's acceleration and an S-curve's jerk jump at the phase boundaries
            // (and at the start and the end): there either side's value is right
            auto near_jump = [&](double t) {
                if (shape == jl::kShapeSine) return false;
                for (int i = 0; i < p.nseg; ++i)
                    if (std::fabs(t - p.seg[i].t0) <= 1e-6 * std::max(1.0, (double)p.duration)) return true;
                return false;
            };
            if (kind == "P") {
                double T, tv, tu;
                ss >> T >> tv >> tu;
                plan.check(std::fabs(p.accel_time - T), kRtolPlan * tu, where.str() + " accel_time");
                plan.check(std::fabs(p.cruise_time - tv), kRtolPlan * tu, where.str() + " cruise_time");
                plan.check(std::fabs(p.duration - tu), kRtolPlan * tu, where.str() + " duration");
            } else if (kind == "S") {
                double t, j, a, v, x;
                ss >> t >> j >> a >> v >> x;
                jl::Sample s;
                jl::sample(p, (float)t, &s);
                smp.check(std::fabs(s.jerk - j), near_jump(t) ? 2.000001 * sj : tol(kRtolSample, sj, sj * w, t, 4), where.str() + " jerk");
                smp.check(std::fabs(s.accel - a), near_jump(t) && shape == jl::kShapeStep ? 2.000001 * sa : tol(kRtolSample, sa, sj, t, 4), where.str() + " accel");
                smp.check(std::fabs(s.velocity - v), tol(kRtolSample, sv, sa, t, 4), where.str() + " velocity");
                smp.check(std::fabs(s.position - x), tol(kRtolSample, sx, sv, t, 4), where.str() + " position");
            } else {
                double Ts;
                long n;
                ss >> Ts >> n;
                jl::PlanStepper stepper, fstep;
                Stat& stq = host_seg ? hstp : stp;   // (G: counted apart)
                // positions in counts as on the device (448 per rev x1): the fixed point's
                // absolute bound 2^-32 (n + n^2 + n^3) < 6.2e-5 counts (n < 64) is in counts
                const double cpr = 448.0 / (2.0 * M_PI);
                const double fx_bound = std::ldexp(1.0, -32) * (64.0 + 64.0 * 64.0 + 64.0 * 64.0 * 64.0) / cpr;
                // the pulses' integer sinusoids (docs/THEORY.md): |error| < 1 + n (1 + eps/2) +
                // n (n + 1)/2 units 2^(s - 32) at n < 64 (< 2206 units, eps <= 4), the unit from
                // the amplitude a (a 2^(32 - s) < 2^28: s = floor(log2 a) + 5, at least 0), for
                // the plan's largest pulse: position a = cpr |B|, B = jp / w^3 (counts), velocity
                // a = cpr w |B|, the feedforward below a = alpha w^2 |B| (ticks)
                auto pulse_unit = [](double a) {
                    if (!(a > 0.0)) return std::ldexp(1.0, -32);
                    const int e = std::max(0, (int)std::floor(std::log2(a * (1.0 + 1e-6))) + 5);
                    return std::ldexp(1.0, std::min(e, 31) - 32);
                };
                const double kSinUnits = 1.0 + 63.0 * 3.0 + 63.0 * 64.0 / 2.0;
                double bmax = 0.0, wbmax = 0.0, w2bmax = 0.0;
                for (int i = 0; i < p.nseg; ++i)
                    if (jl::is_pulse(p.seg[i])) {
                        const double wi = p.seg[i].w, bi = std::fabs((double)p.seg[i].jp) / (wi * wi * wi);
                        bmax = std::max(bmax, bi);
                        wbmax = std::max(wbmax, wi * bi);
                        w2bmax = std::max(w2bmax, wi * wi * bi);
                    }
                const double sx_bound = bmax > 0 ? kSinUnits * pulse_unit(cpr * bmax) / cpr : 0.0;
                const double sv_bound = wbmax > 0 ? kSinUnits * pulse_unit(cpr * wbmax) / cpr : 0.0;
                stepper.start(p, (float)Ts, 0.0f, 0.0f, (float)cpr, (float)cpr);
                // never prepared ahead: every change of chunk takes the slow path, which must
                // give the same samples and count each change as a miss
                jl::PlanStepper lazy;
                lazy.start(p, (float)Ts, 0.0f, 0.0f, (float)cpr, (float)cpr);
                uint8_t lazy_seg = lazy.segment();
                long lazy_changes = 0;
                // the feedforward path (Q16.16): alpha a with alpha = 1000 / peak accel
                const float alpha = sa > 0 ? (float)(1000.0 / sa) : 1.0f;
                fstep.start(p, (float)Ts, alpha, 0.0f, 1.0f, 1.0f);
                const double sf_bound = w2bmax > 0 ? kSinUnits * pulse_unit(alpha * w2bmax) / alpha : 0.0;
                // The integer recurrence itself: from a chunk's first observed state (y, D, eps =
                // E 2^(-8 eb)), the same recurrence in double (exact to ~1e-16) must stay within
                // j (j + 1)/2 units after j steps (the product's floors), and eps must be
                // 4 sin^2(w Ts / 2) (as the float32 closed form gives it).
                uint32_t rk0 = 0xFFFFFFFFu;
                double ryd = 0.0, rDd = 0.0, reps = 0.0;
                long rj = 0;
                for (long k = 0; k < n; ++k) {
                    if (!std::getline(in, line)) { stq.check(1, 0, "truncated stepper block"); break; }
                    ++lineno;
                    std::istringstream ls(line);
                    std::string tag;
                    double j, a, v, x;
                    ls >> tag >> j >> a >> v >> x;
                    jl::Sample s;
                    stepper.next(&s);
                    {
                        const jl::PlanStepper::Coef& c = stepper.chunk();
                        if (c.sine && c.seg < p.nseg) {
                            if (c.k0 != rk0) {
                                rk0 = c.k0;
                                ryd = c.yx;
                                rDd = c.Dx;
                                reps = std::ldexp((double)c.E, -8 * c.eb);
                                rj = 0;
                                const double th = 0.5 * (double)p.seg[c.seg].w * (double)(float)Ts;
                                const double eps = 4.0 * std::sin(th) * std::sin(th);
                                // (float32 sin of the float32 angle w Ts / 2: |d eps / d th| <= 4 times its rounding)
                                pulse.check(std::fabs(reps - eps), eps * std::ldexp(1.0, -20) + 4.0 * th * std::ldexp(1.0, -21),
                                          wh0(path, lineno, k) + " pulse eps");
                                pulse.check(std::max(std::fabs((double)c.yx) / std::ldexp(1.0, 28),
                                                   std::fabs((double)c.Dx) / std::ldexp(1.0, 29)), 1.0,
                                          wh0(path, lineno, k) + " pulse sinusoid range");
                            } else {
                                rDd -= reps * ryd;
                                ryd += rDd;
                                ++rj;
                                pulse.check(std::fabs((double)c.yx - ryd), 0.5 * rj * (rj + 1) + 1e-6,
                                          wh0(path, lineno, k) + " pulse recurrence (integer vs double)");
                            }
                        }
                    }
                    float fx, fq, lx;
                    fstep.next_fast(&fx, nullptr, &fq);
                    fstep.prepare();
                    lazy.next_fast(&lx, nullptr, nullptr);
                    if (lazy.segment() != lazy_seg) { ++lazy_changes; lazy_seg = lazy.segment(); }
                    const double fa = fq / alpha;
                    std::ostringstream wh;
                    wh << path << ":" << lineno << " k=" << k;
                    const double t = k * Ts;
                    stq.check(std::fabs(s.jerk - j), near_jump(t) ? 2.000001 * sj : tol(kRtolStepper, sj, sj * w, t, 16), wh.str() + " jerk");
                    stq.check(std::fabs(s.accel - a), near_jump(t) && shape == jl::kShapeStep ? 2.000001 * sa : tol(kRtolStepper, sa, sj, t, 16), wh.str() + " accel");
                    stq.check(std::fabs(s.velocity / cpr - v), tol(kRtolStepper, sv, sa, t, 16) + sv_bound, wh.str() + " velocity");
                    stq.check(std::fabs(s.position / cpr - x), tol(kRtolStepper, sx, sv, t, 16) + fx_bound + sx_bound, wh.str() + " position");
                    stq.check(std::fabs(lx / cpr - x), tol(kRtolStepper, sx, sv, t, 16) + fx_bound + sx_bound, wh.str() + " position (unprepared)");
                    // fixed-point feedforward: the stepper's bound plus the Q16.16 rounding
                    stq.check(std::fabs(fa - a), (near_jump(t) && shape == jl::kShapeStep ? 2.000001 * sa : tol(kRtolStepper, sa, sj, t, 16)) + 2.0 / 65536.0 / alpha + sf_bound,
                              wh.str() + " feedforward (accel)");
                }
                // the idle-time preparation kept up: no chunk computed inside a sample
                stq.check(stepper.misses() + fstep.misses(), 0.5, where.str() + " chunk changes unprepared");
                // the lazy stepper changed chunk through misses only (start() prepares one ahead)
                stq.check(lazy_changes > 1 + (long)lazy.misses(), 0.5, where.str() + " misses not counted");
            }
        } else if (kind == "C") {
            double kpd, kid, kdd, gamma, limit, K, tau, Ts;
            int f, loop;
            ss >> kpd >> kid >> kdd >> gamma >> limit >> K >> tau >> f >> loop >> Ts;
            velocity_loop = loop == 1;
            ctl_Ts = (float)Ts;
            first = true;
            if (!pid.set((float)kpd, (float)kid, (float)kdd, (float)gamma, (float)limit) || !ff.set((float)K, (float)tau)) {
                ctl.check(1, 0, where.str() + " gains refused");
                continue;
            }
            pid.reset();
            use_ff = f != 0;
            ctl_scale = limit;
            // fixed point: e x q_se (counts per rad as on the Uno; the velocity loop's rad/s as
            // they are), u x q_su (PWM ticks per volt, 1023 / limit)
            q_se = loop == 1 ? 1.0 : 448.0 / (2.0 * M_PI);
            q_su = 1023.0 / limit;
            {
                const double g = q_su / q_se;
                if (!pidq.set((float)(kpd * g), (float)(kid * g), (float)(kdd * g), (float)gamma, (float)(limit * q_su))) {
                    ctlq.check(1, 0, where.str() + " fixed-point gains refused");
                    continue;
                }
            }
            pidq.reset();
            q_kabs = (std::fabs(kpd) + 2.0 * std::fabs(kdd)) / (1.0 - std::fabs(gamma));
            q_kid = std::fabs(kid);
            q_gamma = std::fabs(gamma);
            q_emax = 0.0;
            q_acc = 0.0;
        } else if (kind == "c") {
            double r, v, a, y, u, p, i, d, uf;
            int sat;
            ss >> r >> v >> a >> y >> u >> p >> i >> d >> uf >> sat;
            float e;
            if (!velocity_loop) {
                e = (float)r - (float)y;
            } else {
                if (first) y_prev = (float)y;
                e = (float)v - ((float)y - y_prev) / ctl_Ts;
                y_prev = (float)y;
            }
            first = false;
            float uff = use_ff ? ff((float)v, (float)a) : 0.0f;
            jl::ControlParts parts;
            pid.step(e, uff, &parts);
            const double tol = kRtolControl * ctl_scale;
            ctl.check(std::fabs(parts.u - u), tol, where.str() + " u");
            ctl.check(std::fabs(parts.p - p), tol, where.str() + " p");
            ctl.check(std::fabs(parts.i - i), tol, where.str() + " i");
            ctl.check(std::fabs(parts.d - d), tol, where.str() + " d");
            ctl.check(std::fabs(parts.ff - uf), tol, where.str() + " ff");
            ctl.check(parts.saturated != (sat != 0), 0.5, where.str() + " saturated");
            // PidQ: the float path's bound plus the fixed point's (docs/THEORY.md "The fixed-point
            // PID"): e rounded to 2^-17 of its unit, ff to 2^-17 tick, each product floored
            // (<= 2^-16 tick, 3 a step plus the integrator's running sum), each gain within
            // 2^-16 of itself (24-bit mantissa, >= 16 significant bits) or 2^-33 absolute:
            // 2^-16 (|p| + |d| / (1 - |gamma|)) and the integrator's running 2^-16 |kid e|
            {
                bool qsat;
                q_emax = std::max(q_emax, std::fabs(e * q_se));
                const int32_t eq = jl::to_q16((float)(e * q_se));
                const int32_t fq = jl::to_q16((float)(uff * q_su));
                const int32_t uq = pidq.step(eq, fq, &qsat);
                const double lsb = 1.0 / 65536.0;
                q_acc += q_kid * 0.5 * lsb / q_se + lsb / q_su             // integrator: e's rounding, floor,
                         + std::ldexp(std::fabs(q_kid * e), -16)           // gain: 2^-16 relative
                         + std::ldexp(std::fabs(e * q_se), -33) / q_su;     // or 2^-33 tick/unit
                const double tq = kRtolControl * ctl_scale + q_kabs * 0.5 * lsb / q_se
                                  + (4.0 * lsb + 3.0 * lsb) / q_su + q_acc
                                  + std::ldexp(std::fabs(p) + std::fabs(d) / (1.0 - q_gamma), -16)
                                  + 4.0 * std::ldexp(q_emax, -33) / ((1.0 - q_gamma) * q_su);
                ctlq.check(std::fabs(uq * lsb / q_su - u), tq, where.str() + " u (fixed point)");
            }
        } else if (kind == "F") {
            unsigned type, seq;
            std::string ph, fh;
            ss >> type >> seq >> ph >> fh;
            std::vector<uint8_t> pl = from_hex(ph);
            uint8_t buf[jl::kMaxFrame];
            uint8_t n = jl::encode_frame(buf, (uint8_t)type, (uint8_t)seq, pl.data(), (uint8_t)pl.size());
            std::string got = to_hex(buf, n);
            std::string what = got != fh ? " frame " + got + " != " + fh : std::string();
            // the Uno's path: straight into a transmit ring, at heads that make it wrap (a
            // 64-byte ring as on the Uno when the frame fits, else 128 bytes); the bytes
            // around the frame stay untouched (one record per frame: both paths must agree)
            const unsigned size = n <= 63 ? 64u : 128u;
            for (unsigned head : {0u, (seq * 7u + 3u) % size, size - 5u, size - 1u}) {
                uint8_t ring[128];
                for (unsigned j = 0; j < size; ++j) ring[j] = (uint8_t)(0x3C ^ j);
                const uint8_t end = jl::encode_frame_ring(ring, (uint8_t)(size - 1), (uint8_t)head, (uint8_t)type,
                                                          (uint8_t)seq, pl.data(), (uint8_t)pl.size());
                uint8_t lin[jl::kMaxFrame];
                for (unsigned j = 0; j < n; ++j) lin[j] = ring[(head + j) % size];
                bool outside = false;
                for (unsigned j = n; j < size; ++j) outside |= ring[(head + j) % size] != (uint8_t)(0x3C ^ ((head + j) % size));
                const std::string rgot = to_hex(lin, n);
                if (what.empty() && (rgot != fh || end != (head + n) % size || outside))
                    what = " ring frame at " + std::to_string(head) + " " + rgot + " != " + fh + " end " +
                           std::to_string(end) + (outside ? " (bytes outside the frame written)" : "");
            }
            enc.check(!what.empty(), 0.5, where.str() + what);
        } else if (kind == "D") {
            std::string sh;
            long nframes, dropped;
            ss >> sh >> nframes >> dropped;
            std::vector<uint8_t> stream = from_hex(sh);
            jl::FrameParser parser;
            std::vector<std::string> got;
            for (uint8_t b : stream) {
                if (!parser.feed(b)) continue;
                do {
                    const jl::Frame& f = parser.frame();
                    std::ostringstream o;
                    o << (unsigned)f.type << " " << (unsigned)f.seq << " " << to_hex(f.payload, f.len);
                    got.push_back(o.str());
                } while (parser.process());
            }
            std::vector<std::string> want;
            for (long k = 0; k < nframes; ++k) {
                std::getline(in, line);
                ++lineno;
                want.push_back(line.substr(2));
            }
            dec.check(got != want, 0.5, where.str() + " frames differ (" + std::to_string(got.size()) + " decoded, " + std::to_string(want.size()) + " expected)");
            dec.check(std::fabs((double)parser.dropped() - (double)dropped), 0.5,
                      where.str() + " dropped " + std::to_string(parser.dropped()) + " != " + std::to_string(dropped));
        } else if (kind == "H") {
            unsigned n, N;
            float a[jl::kShaperMaxTaps];
            uint8_t d[jl::kShaperMaxTaps];
            ss >> n;
            for (unsigned i = 0; i < jl::kShaperMaxTaps; ++i) {
                std::string h;
                ss >> h;
                const uint32_t bits = static_cast<uint32_t>(std::stoul(h, nullptr, 16));
                std::memcpy(&a[i], &bits, 4);
            }
            for (unsigned i = 0; i < jl::kShaperMaxTaps; ++i) {
                unsigned v;
                ss >> v;
                d[i] = static_cast<uint8_t>(v);
            }
            ss >> N;
            jl::Shaper sh;
            // (the payload's little-endian float32s: the host's own layout)
            sh.set(static_cast<uint8_t>(n), reinterpret_cast<const uint8_t*>(a), d);
            sh.reset();
            for (unsigned k = 0; k < N; ++k) {
                std::getline(in, line);
                ++lineno;
                std::istringstream ls(line);
                std::string h;
                long long R, Rs;
                long v, acc;
                ls >> h >> R >> Rs >> v >> acc;
                jl::Q32 q;
                q.lo = static_cast<uint32_t>(static_cast<unsigned long long>(R));
                q.hi = static_cast<int32_t>(R >> 32);
                int32_t gv, ga;
                sh.apply(&q, &gv, &ga);
                sh.prepare();
                const long long got = static_cast<long long>((static_cast<unsigned long long>(static_cast<uint32_t>(q.hi)) << 32) | q.lo);
                std::ostringstream w;
                w << path << ":" << lineno << " k=" << k << " Rs " << got << " v " << gv << " a " << ga;
                shp.check(got != Rs || gv != v || ga != acc, 0.5, w.str());
            }
        } else if (kind == "R") {
            // R <x as float32 bits, hex> <the true cube root of that float, float64>: within
            // 2 ulp of the float32 nearest the root (0 and inf exactly)
            std::string h, ws;
            ss >> h >> ws;
            const double want = std::strtod(ws.c_str(), nullptr);   // (">>" reads no "inf")
            const uint32_t bits = static_cast<uint32_t>(std::stoul(h, nullptr, 16));
            float x;
            std::memcpy(&x, &bits, 4);
            const double got = jl::cube_root(x);
            const float wf = static_cast<float>(want);
            double err;
            if (std::isinf(want) || want == 0.0) {
                err = got == want ? 0.0 : 1e300;
            } else {
                const double ulp = std::nextafter(wf, INFINITY) - wf;
                err = std::fabs(got - want) / ulp;
            }
            std::ostringstream w;
            w << where.str() << " x " << x << " got " << got << " want " << want;
            root.check(err, 2.0, w.str());
        } else {
            std::fprintf(stderr, "%s: unknown record %s\n", where.str().c_str(), kind.c_str());
            return 2;
        }
    }
    int fail = 0;
    for (Stat* s : {&plan, &smp, &stp, &pulse, &ctl, &ctlq, &enc, &dec, &shp, &hstp, &root}) {
        std::printf("%s records=%ld failures=%ld worst_error_over_tol=%.3g at %s\n", s->name, s->records,
                    s->failures, s->worst, s->worst_what.empty() ? "-" : s->worst_what.c_str());
        if (s->failures) fail = 1;
    }
    return fail;
}

// ------------------------------------------------------------------------- device mode

class HostHal : public jl::Hal {
public:
    HostHal(double K, double tau, double supply, int encoder = 1)
        : K_(K), tau_(tau), supply_(supply), encoder_(encoder) {}
    void write_frame(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t n) override {
        uint8_t buf[jl::kMaxFrame];
        const uint8_t len = jl::encode_frame(buf, type, seq, payload, n);
        std::printf("tx %u %s\n", ms_, to_hex(buf, len).c_str());
    }
    int32_t counts() override {
        return encoder_ * static_cast<int32_t>(std::floor(theta_ * cpr_ / (2 * M_PI))) - zero_;
    }
    void zero_counts() override { zero_ += counts(); }
    void set_decoding(uint8_t decoding) override { cpr_ = 448.0 * decoding; }
    void set_pwm(int16_t pwm) override {
        if (pwm != pwm_) std::printf("pwm %u %d\n", ms_, pwm);
        pwm_ = pwm;
    }
    void set_period(uint16_t ticks) override { period_ = ticks; phase_ = 0; }
    uint32_t millis() override { return ms_; }
    bool simulated_plant() override { return true; }

    // One 1 ms tick: the motor moves for 1 ms under the current voltage (exact ZOH of
    // K/(s(tau s + 1))), then the timer ISR raises the control flag every `period_` ticks.
    bool tick() {
        const double h = 1e-3, a = std::exp(-h / tau_);
        const double u = pwm_ / 1023.0 * supply_;
        const double w0 = omega_;
        omega_ = a * w0 + (1 - a) * K_ * u;
        theta_ += tau_ * (1 - a) * w0 + K_ * u * (h - tau_ * (1 - a));
        ++ms_;
        if (++phase_ >= period_) { phase_ = 0; return true; }
        return false;
    }

private:
    double K_, tau_, supply_;
    int encoder_;
    double theta_ = 0.0, omega_ = 0.0, cpr_ = 448.0;
    int32_t zero_ = 0;
    int16_t pwm_ = 0;
    uint16_t period_ = 5, phase_ = 0;
    uint32_t ms_ = 0;
};

int run_device(double K, double tau, double supply, int encoder) {
    HostHal hal(K, tau, supply, encoder);
    jl::DeviceConfig cfg = {1000, 1023, 448, 1, 0, 0};
    jl::Device dev(hal, cfg);
    dev.begin();
    std::string line;
    while (std::getline(std::cin, line)) {
        std::istringstream ss(line);
        std::string cmd;
        ss >> cmd;
        if (cmd == "rx") {
            std::string h;
            ss >> h;
            for (uint8_t b : from_hex(h)) dev.on_byte(b);
        } else if (cmd == "ms") {
            long n;
            ss >> n;
            for (long i = 0; i < n; ++i) {
                if (hal.tick() && dev.state() != jl::Device::kIdle) {   // as loop() in the sketch
                    const bool produced = dev.control();
                    dev.reference();
                    if (produced) dev.report();
                    dev.background();
                }
                dev.poll();
            }
        } else if (cmd == "idle") {
            dev.on_rx_idle();
        } else if (cmd == "quit") {
            break;
        } else if (!cmd.empty()) {
            std::fprintf(stderr, "unknown command %s\n", cmd.c_str());
            return 2;
        }
        std::fflush(stdout);
    }
    return 0;
}

}  // namespace

// jl_host fixed: the fixed-point helpers (jl_fixed) on records from stdin, one result line each:
//   w A B        -> "LO HI"      mul_s32x32 (the full signed product's two words)
//   m A MANT S   -> "R"          mul_q(A, {MANT, S})
//   g BITS       -> "OK MANT S"  to_qgain of the float32 with these IEEE bits
//   q BITS       -> "R"          to_q16 of the float32 with these IEEE bits
//   s A B        -> "SUM DIFF"   add_sat, sub_sat
//   p BITS TOP   -> "R"          round_clamp of the float32 with these IEEE bits
int run_fixed() {
    std::string line;
    while (std::getline(std::cin, line)) {
        std::istringstream ss(line);
        std::string k;
        if (!(ss >> k)) continue;
        if (k == "w") {
            long long a, b;
            ss >> a >> b;
            uint32_t lo;
            int32_t hi;
            jl::mul_s32x32((int32_t)a, (int32_t)b, &lo, &hi);
            std::printf("%lu %ld\n", (unsigned long)lo, (long)hi);
        } else if (k == "m") {
            long long a, m;
            int sh;
            ss >> a >> m >> sh;
            jl::QGain g = {(int32_t)m, (uint8_t)sh};
            std::printf("%ld\n", (long)jl::mul_q((int32_t)a, g));
        } else if (k == "g" || k == "q") {
            unsigned long bits;
            ss >> bits;
            uint32_t b32 = (uint32_t)bits;
            float x;
            std::memcpy(&x, &b32, 4);
            if (k == "q") {
                std::printf("%ld\n", (long)jl::to_q16(x));
            } else {
                jl::QGain g = {0, 0};
                const bool ok = jl::to_qgain(x, &g);
                std::printf("%d %ld %u\n", ok ? 1 : 0, (long)g.mant, (unsigned)g.shift);
            }
        } else if (k == "p") {
            unsigned long bits;
            int top;
            ss >> bits >> top;
            uint32_t b32 = (uint32_t)bits;
            float x;
            std::memcpy(&x, &b32, 4);
            std::printf("%d\n", (int)jl::round_clamp(x, (int16_t)top));
        } else if (k == "s") {
            long long a, b;
            ss >> a >> b;
            std::printf("%ld %ld\n", (long)jl::add_sat((int32_t)a, (int32_t)b), (long)jl::sub_sat((int32_t)a, (int32_t)b));
        }
    }
    return 0;
}

int main(int argc, char** argv) {
    if (argc >= 3 && std::strcmp(argv[1], "vectors") == 0) return run_vectors(argv[2]);
    if (argc >= 2 && std::strcmp(argv[1], "fixed") == 0) return run_fixed();
    if (argc >= 2 && std::strcmp(argv[1], "device") == 0) {
        double K = argc > 2 ? std::atof(argv[2]) : 32.4;
        double tau = argc > 3 ? std::atof(argv[3]) : 0.025;
        double vs = argc > 4 ? std::atof(argv[4]) : 12.0;
        int encoder = argc > 5 ? std::atoi(argv[5]) : 1;
        if (encoder < -1 || encoder > 1) { std::fprintf(stderr, "encoder must be 1, -1 or 0\n"); return 2; }
        return run_device(K, tau, vs, encoder);
    }
    std::fprintf(stderr, "usage: jl_host vectors FILE | jl_host device [K tau supply [encoder]]\n");
    return 2;
}
