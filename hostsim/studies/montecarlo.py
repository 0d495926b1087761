"""Monte Carlo robustness: the firmware in the loop under model, sensor and timing uncertainty.

``python -m hostsim montecarlo [--runs 200] [--duration 10] [--gains FILE ...] [--jobs N]
[--seed S] [--kw0] [--brick] [--out DIR]``

Each run starts from scenarios/montecarlo_base.json (the physical plant: the robot), or with
``--brick`` from scenarios/brick_realistic.json (the unkind brick: released at 0.017 rad with
the firmware told 0), and draws, from its own generator seeded by (seed, run index):

- every mass, length and inertia (links, wheels, wheel radius, track, rotor inertias Jm)
  x U(0.8, 1.2); every motor constant (Km, Ke, Ra, friction beta) x U(0.9, 1.1); the
  firmware keeps the nominal wheel radius, so a perturbed R_w is also a scale error on d;
- gyro bias U(-2, 2) deg/s and white noise of standard deviation U(0, 0.5) deg/s: within
  the firmware's calibration stillness check (rate spread <= 4 deg/s over 1 s), which a
  larger noise would trip; a run the firmware refuses to start is counted apart;
- encoder quantization (always: 1 count = 1 degree, hostsim.world.sensors), one extra tick of
  input delay with probability 1/2, and loop wake-up jitter |N(0, s)|, s ~ U(0, 1) ms;
- the release angle th1(0) ~ U(-0.04, 0.04) rad;
- with ``--brick``, the brick's effects around their realistic values (BRICK_DRAWS, after the
  draws above, so those stay the same): access and compute times x U(0.8, 1.2), each motor's
  dead band and backlash x U(0.5, 1.5), gyro latency U(1, 5) ms, the -2 % scale error on
  either sense of rotation, the bias ramp of either sign, battery resistance U(0.1, 0.3) ohm,
  ...; the brick's timing replaces the extra tick of delay and the jitter (both 0), and its
  runs go through the fake EV3 tree (the timing acts there).

The same draws are used for every gains file (common random numbers: the gains are
compared on identical robots). A run succeeds when the firmware completes the duration
(no fall or joint-limit stop), |th1| stays below 30 degrees and ends below 0.1 rad.
Results do not depend on --jobs (see hostsim.sim.parallel).
"""
import argparse
import dataclasses
import json
import os
import time

import hostsim
import numpy as np

from hostsim.model.gains import with_law
from hostsim.model.params import MOTOR_ROLES
from hostsim.paths import REPO_ROOT, out_dir
from hostsim.studies.stats import distribution, trio
from tipbot_fw.gains import load_gains_document

GEOMETRY = ("m1_kg", "m2_kg", "m3_kg", "mw_kg", "l1_m", "l2_m", "l3_m", "rw_m", "track_m",
            "j1_kg_m2", "j2_kg_m2", "j3_kg_m2", "jw_kg_m2") + tuple(r + "_jm_kg_m2" for r in MOTOR_ROLES)
MOTOR = tuple("%s_%s" % (r, f) for r in MOTOR_ROLES for f in ("km_nm_a", "ke_v_s", "ra_ohm", "beta_nm_s"))
GEOMETRY_SPREAD = 0.20
MOTOR_SPREAD = 0.10
GYRO_BIAS_DPS = 2.0
GYRO_NOISE_MAX_DPS = 0.5
JITTER_MAX_S = 0.001
TH1_0_MAX_RAD = 0.04
FINAL_TH1_RAD = 0.1
DEFAULT_GAINS = ("gains/paper.json", "gains/physical.json")
BASE_SCENARIO = "montecarlo_base"
BRICK_SCENARIO = "brick_realistic"

# How each brick field is drawn around the preset's value v (hostsim.sim.scenario.Brick):
# ("scale", lo, hi): v x U(lo, hi), one factor for the field; ("each", lo, hi): one factor per
# motor; ("uniform", lo, hi): U(lo, hi) whatever v; ("signed", lo, hi): v x U(lo, hi) x (+1 or -1);
# ("either", lo, hi): a (positive, negative) pair with v's nonzero error x U(lo, hi) on a
# random one of the two. Fields not listed keep the preset's value.
BRICK_DRAWS = {
    "tacho_access_s": ("scale", 0.8, 1.2), "sensor_access_s": ("scale", 0.8, 1.2),
    "compute_s": ("scale", 0.8, 1.2), "cpu_steal": ("uniform", 0.10, 0.20),
    "late_wake_probability": ("scale", 0.5, 1.5), "stall_rate_hz": ("scale", 0.5, 1.5),
    "friction_deadband_pct": ("each", 0.5, 1.5), "backlash_deg": ("each", 0.5, 1.5),
    "gyro_latency_s": ("uniform", 0.001, 0.005), "gyro_freeze_interval_s": ("scale", 0.5, 1.5),
    "gyro_scale_error": ("either", 0.5, 1.5), "gyro_bias_walk_dps_rt_s": ("scale", 0.5, 1.5),
    "gyro_bias_ramp_dps_s": ("signed", 0.0, 1.5), "gyro_rate_step_dps": ("scale", 0.5, 1.5),
    "gyro_mode_write_s": ("scale", 0.5, 1.5), "battery_r_ohm": ("uniform", 0.1, 0.3),
}


def draw(rng, brick=None):
    """One run's perturbations (a dict of scenario fields); with brick (the base's Brick), its
    effects drawn around their values too."""
    scale = {n: float(rng.uniform(1 - GEOMETRY_SPREAD, 1 + GEOMETRY_SPREAD)) for n in GEOMETRY}
    scale.update({n: float(rng.uniform(1 - MOTOR_SPREAD, 1 + MOTOR_SPREAD)) for n in MOTOR})
    d = {
        "param_scale": scale,
        "gyro_bias_dps": float(rng.uniform(-GYRO_BIAS_DPS, GYRO_BIAS_DPS)),
        "gyro_noise_dps": float(rng.uniform(0.0, GYRO_NOISE_MAX_DPS)),
        "extra_delay_ticks": int(rng.integers(0, 2)),
        "jitter_s": float(rng.uniform(0.0, JITTER_MAX_S)),
        "th1_0_rad": float(rng.uniform(-TH1_0_MAX_RAD, TH1_0_MAX_RAD)),
        "seed": int(rng.integers(0, 2 ** 31 - 1)),
    }
    if brick is not None and not brick.ideal:
        d["brick"] = draw_brick(rng, brick)
        if brick.timed:
            d["extra_delay_ticks"], d["jitter_s"] = 0, 0.0
    return d


def draw_brick(rng, brick):
    """{brick field: drawn value} (lists for the tuples) around the preset's (BRICK_DRAWS)."""
    out = {}
    for name, (how, lo, hi) in BRICK_DRAWS.items():
        v = getattr(brick, name)
        if how == "scale":
            f = float(rng.uniform(lo, hi))
            out[name] = [f * x for x in v] if isinstance(v, tuple) else f * v
        elif how == "each":
            out[name] = [float(rng.uniform(lo, hi)) * x for x in v]
        elif how == "uniform":
            out[name] = float(rng.uniform(lo, hi))
        elif how == "signed":
            out[name] = v * float(rng.uniform(lo, hi)) * (1 if rng.random() < 0.5 else -1)
        else:     # "either"
            e = min(v) if min(v) < 0 else max(v)
            e *= float(rng.uniform(lo, hi))
            out[name] = [e, 0.0] if rng.random() < 0.5 else [0.0, e]
    return out


def scenario_for(base, d, duration_s=None):
    x0 = list(base.x0_si)
    x0[2] = d["th1_0_rad"]
    brick = base.brick
    if "brick" in d:
        brick = dataclasses.replace(brick, **{k: tuple(v) if isinstance(v, list) else v for k, v in d["brick"].items()})
    sc = dataclasses.replace(
        base, param_scale=d["param_scale"], extra_delay_ticks=d["extra_delay_ticks"], jitter_s=d["jitter_s"],
        seed=d["seed"], x0_si=tuple(x0), brick=brick,
        sensors=dataclasses.replace(base.sensors, gyro_bias_dps=d["gyro_bias_dps"], gyro_noise_dps=d["gyro_noise_dps"]))
    if duration_s is not None:
        sc = dataclasses.replace(sc, duration_s=float(duration_s))
    return sc


_DOCS = {}


def gains_document(path, zero_kw):
    """The gains document of a file, with K_w zeroed on request (cached per process)."""
    key = (path, zero_kw)
    if key not in _DOCS:
        doc = load_gains_document(path)[0]
        if zero_kw:
            doc = with_law(doc, k_w=np.zeros((5, 5)), note=" + K_w = 0")
        _DOCS[key] = doc
    return _DOCS[key]


def run_one(task):
    """Worker: one Monte Carlo run -> a JSON-ready row (with the figures of the perfect-
    measurement run of the same robot: hostsim.sim.linear_sim.IdealController)."""
    from hostsim.sim import metrics
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.linear_sim import simulate_nonlinear
    from tipbot_fw.gains import gains_from_dict

    label, gains_path, zero_kw, base, index, seed, duration_s = task
    d = draw(np.random.default_rng([seed, index]), base.brick)
    sc = scenario_for(base, d, duration_s)
    doc = gains_document(gains_path, zero_kw)
    t0 = time.perf_counter()
    # the brick's timing and mode writes act through the fake EV3 tree; otherwise memory is faster;
    # with its log: saturation from its flags
    run = run_firmware(sc, gains_doc=doc, sysfs=sc.brick.needs_sysfs)
    wall = time.perf_counter() - t0
    g = gains_from_dict(doc, gains_path)
    m = metrics.compute(run, sc, g.u_max_v)
    ideal = metrics.compute(simulate_nonlinear(g, sc, ideal=True), sc, g.u_max_v)
    x, u = run.x, run.u
    th1 = np.abs(x[:, 2])
    completed = bool(run.completed)
    success = completed and bool(np.all(th1 < metrics.UPRIGHT_LIMIT_RAD)) and float(th1[-1]) < FINAL_TH1_RAD
    return {
        "gains": label, "index": index, "success": success, "exit_code": run.exit_code,
        "stop_reason": run.stop_reason, "refused": run.stop_reason == "calibration",
        "simulated_s": float(run.t_s[-1]), "wall_s": wall,
        "final_abs_d_m": float(np.max(np.abs(x[-1, :2] - run.d_origin_m))),
        "peak_abs_th1_rad": float(th1.max()), "peak_abs_th2_rad": float(np.abs(x[:, 3]).max()),
        "peak_abs_th3_rad": float(np.abs(x[:, 4]).max()), "final_abs_th1_rad": float(th1[-1]),
        "peak_abs_u_v": float(np.abs(u[:, [0, 1, 3, 4]]).max()),
        "saturated_fraction": m["saturated_fraction"], "rms_u_v": m["rms_u_v"], "ideal_rms_u_v": ideal["rms_u_v"],
        "rms_th1_after_transient_rad": m["rms_th1_after_transient_rad"],
        "oscillation_above_1hz": m["oscillation_above_1hz"],
        "draw": d,
    }


def variants(gains_paths, kw0, only_kw0=False):
    """[(label, path, zero_kw)]: each gains file, plus its K_w = 0 twin with kw0."""
    out = []
    for path in gains_paths:
        path = path if os.path.isabs(path) else os.path.join(REPO_ROOT, path)
        name = os.path.splitext(os.path.basename(path))[0]
        if not only_kw0:
            out.append((name, path, False))
        if kw0 or only_kw0:
            out.append((name + " K_w=0", path, True))
    return out


def warm_models(plant_variants=("physical",)):
    """Generate the model code cache once, before the workers would race to."""
    from hostsim.model.equations import RobotModel
    from hostsim.model.params import load_params
    for v in plant_variants:
        RobotModel(v, load_params())


def run_montecarlo(runs=200, duration_s=None, gains_paths=DEFAULT_GAINS, kw0=False, jobs=None, seed=0,
                   base=None, desc="Monte Carlo", only_kw0=False):
    """-> {label: {"runs": [rows], "summary": {...}}, "_meta": {...}}. base: the base scenario
    (default scenarios/montecarlo_base.json; BRICK_SCENARIO for the unkind brick)."""
    from hostsim.sim.parallel import default_jobs, run_tasks
    from hostsim.sim.scenario import load_scenario

    if base is None or isinstance(base, str):
        base = load_scenario(base or BASE_SCENARIO)
    tasks = [(label, path, zk, base, i, seed, duration_s)
             for label, path, zk in variants(gains_paths, kw0, only_kw0) for i in range(runs)]
    jobs = default_jobs() if jobs is None else jobs
    t0 = time.perf_counter()
    rows = run_tasks(run_one, tasks, jobs=jobs, desc=desc, warm=lambda: warm_models((base.plant_variant,)))
    wall = time.perf_counter() - t0
    out = {}
    for label, _, _ in variants(gains_paths, kw0, only_kw0):
        mine = [r for r in rows if r["gains"] == label]
        out[label] = {"runs": mine, "summary": summarize(mine)}
    out["_meta"] = {"runs_per_gains": runs, "duration_s": duration_s or base.duration_s, "jobs": jobs,
                    "seed": seed, "wall_s": wall, "total_runs": len(tasks),
                    "runs_per_s": len(tasks) / wall if wall > 0 else None,
                    "plant_variant": base.plant_variant, "plant_method": base.plant_method,
                    "base": base.name, "brick": not base.brick.ideal}
    return out


def summarize(rows):
    n = len(rows)
    ok = [r for r in rows if r["success"]]
    started = [r for r in rows if not r["refused"]]
    tilt = [r["peak_abs_th1_rad"] for r in started]
    volt = [r["peak_abs_u_v"] for r in started]
    by_delay = {}
    for delay in (0, 1):
        sel = [r for r in started if r["draw"]["extra_delay_ticks"] == delay]
        by_delay[str(delay)] = (sum(r["success"] for r in sel) / len(sel)) if sel else None
    reasons = {}
    for r in rows:
        if not r["success"]:
            # a run that completed failed the upright criterion
            why = "tilted" if r["stop_reason"] == "completed" else (r["stop_reason"] or "?")
            reasons[why] = reasons.get(why, 0) + 1
    done = [r for r in started if r["simulated_s"] > 2.5 and r.get("rms_u_v")]
    wheel_ratio = [max(r["rms_u_v"][i] / r["ideal_rms_u_v"][i] for i in (0, 1)) for r in done]
    return {
        "runs": n, "successes": len(ok), "success_rate": len(ok) / n if n else None,
        "refused": n - len(started), "failures_by_reason": reasons,
        "success_rate_by_extra_delay": by_delay,
        "peak_abs_th1_rad": distribution(tilt),
        "peak_abs_u_v": distribution(volt),
        "saturated_fraction": distribution([r["saturated_fraction"] for r in done]),
        "wheel_rms_u_ratio_to_ideal": distribution(wheel_ratio),
        "joint_rms_u_v": distribution([max(r["rms_u_v"][2:]) for r in done]),
        "rms_th1_after_transient_rad": distribution([r["rms_th1_after_transient_rad"] for r in done]),
        "final_abs_d_m": distribution([r["final_abs_d_m"] for r in started]),
        "mean_wall_s": float(np.mean([r["wall_s"] for r in rows])) if rows else None,
    }


def format_table(results):
    head = "%-22s %5s %8s %7s %22s %22s %s" % ("gains", "runs", "success", "refused",
                                               "peak|th1| med/p95/max", "peak|u| V med/p95/max", "failures")
    head2 = "%-22s %22s %22s %22s %22s" % ("", "sat % med/p95/max", "wheel RMS / ideal", "joint RMS V",
                                           "th1 RMS after 2 s")
    lines = ["(base scenario %s)" % results["_meta"].get("base", BASE_SCENARIO), head, head2]
    for label, res in results.items():
        if label.startswith("_"):
            continue
        s = res["summary"]
        fails = ", ".join("%s %d" % kv for kv in sorted(s["failures_by_reason"].items())) or "-"
        lines.append("%-22s %5d %7.1f%% %7d %22s %22s %s" % (
            label, s["runs"], 100 * s["success_rate"], s["refused"], trio(s["peak_abs_th1_rad"], "%.3f"),
            trio(s["peak_abs_u_v"], "%.2f"), fails))
        if s.get("wheel_rms_u_ratio_to_ideal"):
            sat = {k: (100 * v if isinstance(v, float) else v) for k, v in s["saturated_fraction"].items()}
            lines.append("%-22s %22s %22s %22s %22s" % (
                "", trio(sat, "%.2f"), trio(s["wheel_rms_u_ratio_to_ideal"], "%.2f"),
                trio(s["joint_rms_u_v"], "%.3f"), trio(s["rms_th1_after_transient_rad"], "%.4f")))
    m = results["_meta"]
    lines.append("%d runs of %g s in %.1f s on %d workers (%.2f runs/s, %.2f s per run per worker)" % (
        m["total_runs"], m["duration_s"], m["wall_s"], m["jobs"], m["runs_per_s"] or 0,
        m["wall_s"] * m["jobs"] / max(1, m["total_runs"])))
    return "\n".join(lines)


def write(results, out_dir, name="montecarlo"):
    """out_dir/NAME.json and NAME.png; -> the figure's file name."""
    from hostsim.studies import plots
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, name + ".json"), "w") as f:
        json.dump(results, f, indent=1, sort_keys=True)
    title = ("the realistic brick's effects drawn around their values" if results["_meta"].get("brick")
             else "parameter, sensor and timing uncertainty")
    return plots.montecarlo_figure({k: v for k, v in results.items() if not k.startswith("_")},
                                   os.path.join(out_dir, name + ".png"), title)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("montecarlo"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200, help="runs per gains file (default 200)")
    ap.add_argument("--duration", type=float, default=None, help="seconds per run (default: the base scenario's, 10)")
    ap.add_argument("--gains", nargs="+", default=list(DEFAULT_GAINS), help="gains files (default gains/paper.json gains/physical.json)")
    ap.add_argument("--kw0", action="store_true", help="also run each gains file with K_w = 0 (diagnosis)")
    ap.add_argument("--brick", action="store_true", help="the unkind brick: scenarios/brick_realistic.json with its "
                    "effects drawn around their realistic values (default: scenarios/montecarlo_base.json)")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    ap.add_argument("--out", default=out_dir("montecarlo"), help="output directory (default out/montecarlo)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    res = run_montecarlo(args.runs, args.duration, args.gains, args.kw0, args.jobs, args.seed,
                         base=BRICK_SCENARIO if args.brick else BASE_SCENARIO)
    name = "montecarlo_brick" if args.brick else "montecarlo"
    fig = write(res, args.out, name)
    print(format_table(res))
    print("wrote %s and %s" % (os.path.join(args.out, name + ".json"), os.path.join(args.out, fig)))
    return 0

