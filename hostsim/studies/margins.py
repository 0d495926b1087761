"""Margins: how much of each imperfection the robot takes, and which one costs most.

``python -m hostsim margins [--gains FILE ...] [--coarse] [--ablation-gains FILE ...] [--no-ablation]
[--seeds N] [--jobs N] [--out DIR]``

**Margin sweep.** From scenarios/brick_realistic.json with every brick effect off (released at
0.017 rad with the firmware told 0, 30 s, the gyro's bias and noise of Section 8), each effect
alone is raised until the robot no longer balances; bisection finds the largest value at
which it still does (completes the 30 s with |th1| below 30 degrees, ending below 0.1 rad: the
Monte Carlo's criterion), to the effect's tolerance, assuming that balancing only gets harder
as the effect grows. Effects (MARGINS):

- backlash (deg): the free play of the three Large motors (the Medium's in the realistic
  proportion, 0.5 to 3);
- I/O delay (ms): from the tick's reads to its duties reaching the motors, all four together
  (whole ticks of it as ``extra_delay_ticks``, the rest as ``io_latency_s``);
- dead band (%): the Large motors' Coulomb friction as the duty that starts them at 8 V (the
  Medium's 2.5 times that, as 10 to 4);
- gyro drift (deg/s^2): a bias ramp, each sign (the smaller margin counts);
- push (N s): a horizontal impulse at link 3's centre of mass at t = 10 s, each direction; the
  table gives it beside the bound no law within u_max passes on the study's plant (the LP
  bound of hostsim.studies.push_limit on the physical gains' model, PUSH_BOUND_GAINS);
- gyro freeze (ms): freezes of that length at exponential intervals of 5 s mean;
- single stall (ms): one stall of the whole brick that long at t = 10 s (at a random phase of
  the period), the motors held at their last duties as the H-bridges hold them; the firmware's
  own limit on it (limits.max_stall_s, which this row is what to choose it from) lifted to its
  bound for the search;
- payload (g): a point mass at the top of link 3 (PAYLOAD_AT_M from its joint) from the start
  (issue 22; hostsim.world.load);
- slope up, slope down (deg): a floor rising (falling) that much forward everywhere, the robot
  released 0.017 rad from the vertical as on the flat (its th1, from the floor's normal, the
  slope more); balancing judged on link 1's lean from the vertical. The plant's wheels do not
  slip: a tyre holds only up to tan(alpha) = mu (hostsim.sim.scenario.MAX_SLOPE_DEG).

**Ablation.** The realistic brick itself (every effect on), as the firmware is (it stops when
more than ``limits.max_lost_s`` is lost to late ticks within ``limits.overrun_window_s``), and
then, with that stop lifted (OVERRUN_LIMIT_LIFTED) so that every run shows what the effects do
to the balancing: all effects on, each effect (group) switched off in turn, all off, and each
effect alone; each
over ``--seeds`` seeds (the scenario's seed and the next ones: sensor noise, timing, gyro).
"""
import argparse
import dataclasses
import json
import math
import os
import time

import hostsim
import numpy as np

from hostsim.paths import REPO_ROOT, out_dir
from hostsim.sim.scenario import MAX_SLOPE_DEG
from hostsim.studies.montecarlo import FINAL_TH1_RAD, gains_document, warm_models
from tipbot_fw.config import MAX_LOST_S, MAX_STALL_BOUNDS_S

DEFAULT_GAINS = ("gains/paper.json", "gains/physical.json")
BASE_SCENARIO = "brick_realistic"
PUSH_AT_S = 10.0
FREEZE_INTERVAL_S = 5.0
MEDIUM_BACKLASH_RATIO = 0.5 / 3.0
MEDIUM_DEADBAND_RATIO = 10.0 / 4.0
PAYLOAD_AT_M = 0.1        # the top of link 3 (2 l3 = 10 cm): where a load tips it most
# The study's plant is the physical model of params/robot.json whatever the gains: the push's
# bound is that model's, which the physical gains file carries (2 s: the bounds agree from there)
PUSH_BOUND_GAINS = "gains/physical.json"
PUSH_BOUND_HORIZON_S = 2.0


@dataclasses.dataclass(frozen=True)
class Margin:
    """One effect of the sweep: its name, unit, what the realistic brick has (text, and the
    number the figure marks), the search range (0, hi], the tolerance (x COARSE in make sim),
    the signs tried."""
    key: str
    label: str
    unit: str
    realistic: str
    realistic_value: object
    hi: float
    tol: float
    signs: tuple = (1,)


MARGINS = (
    Margin("backlash", "backlash", "deg", "3 (Large), 0.5 (Medium)", 3.0, 20.0, 0.25),
    Margin("io_delay", "I/O delay", "ms", "2.1-4.3 (each duty at its write)", 4.3, 60.0, 0.25),
    Margin("deadband", "dead band", "%", "4 (Large), 10 (Medium)", 4.0, 40.0, 0.5),
    Margin("gyro_drift", "gyro drift", "deg/s^2", "0.002 (an assumption)", 0.002, 0.1, 0.001, (1, -1)),
    Margin("push", "push on link 3", "N s", "-", None, 2.0, 0.01, (1, -1)),
    Margin("gyro_freeze", "gyro freeze", "ms", "42, one in 20 s", 42.0, 1000.0, 10.0),
    Margin("single_stall", "single stall", "ms", "10-30, one in 20 s", 30.0, 500.0, 5.0),
    Margin("payload", "payload at the top of link 3", "g", "- (issue 22: 100)", None, 1000.0, 10.0),
    Margin("slope_up", "slope up", "deg", "- (issue 22: 5)", None, MAX_SLOPE_DEG, 0.25),
    Margin("slope_down", "slope down", "deg", "- (issue 22: 5)", None, MAX_SLOPE_DEG, 0.25),
)
COARSE = 4.0      # make sim: tolerances x this
# The firmware's loosest overrun stop (the largest lost time, in the shortest window that allows
# it: only a loop at half its rate stops): for the ablation's runs that must go on whatever the
# timing does.
OVERRUN_LIMIT_LIFTED = {"max_lost_s": MAX_LOST_S, "overrun_window_s": 2 * MAX_LOST_S}

# Ablation groups: the brick fields each effect owns (hostsim.sim.scenario.Brick).
GROUPS = (
    ("timing", ("tacho_access_s", "sensor_access_s", "compute_s", "cpu_steal", "late_wake_probability",
                "late_wake_s", "stall_rate_hz", "stall_s")),
    ("encoders", ("encoder_update_s", "encoder_truncate")),
    ("dead band", ("friction_deadband_pct",)),
    ("backlash", ("backlash_deg",)),
    ("gyro latency", ("gyro_latency_s",)),
    ("gyro freezes", ("gyro_freeze_s", "gyro_freeze_interval_s")),
    ("gyro scale", ("gyro_scale_error",)),
    ("gyro drift", ("gyro_bias_walk_dps_rt_s", "gyro_bias_ramp_dps_s")),
    ("gyro steps", ("gyro_rate_step_dps",)),
    ("battery", ("battery_r_ohm", "battery_quantum_v")),
)


def margin_scenario(base, key, value, ts_s):
    """base (every brick effect off) with one effect at value (signed where it has a sign)."""
    from hostsim.sim.scenario import Brick, Payload, Push, Slope

    if key == "payload":
        return dataclasses.replace(base, payload=Payload(value / 1000.0, PAYLOAD_AT_M) if value else None)
    if key in ("slope_up", "slope_down"):
        angle = value if key == "slope_up" else -value
        x0 = list(base.x0_si)
        x0[2] += math.radians(angle)
        return dataclasses.replace(base, slope=Slope(angle) if angle else None, x0_si=tuple(x0))

    if key == "backlash":
        return dataclasses.replace(base, brick=Brick(backlash_deg=(value,) * 3 + (value * MEDIUM_BACKLASH_RATIO,)))
    if key == "deadband":
        return dataclasses.replace(base, brick=Brick(friction_deadband_pct=(value,) * 3
                                                     + (value * MEDIUM_DEADBAND_RATIO,)))
    if key == "io_delay":
        delay_s = value / 1000.0
        ticks = int(delay_s // ts_s + 1e-9)
        return dataclasses.replace(base, extra_delay_ticks=ticks, io_latency_s=max(0.0, delay_s - ticks * ts_s))
    if key == "gyro_drift":
        return dataclasses.replace(base, brick=Brick(gyro_bias_ramp_dps_s=value))
    if key == "push":
        return dataclasses.replace(base, pushes=(Push(PUSH_AT_S, link=3, impulse_n_s=value),))
    if key == "single_stall":
        limits = dict(base.firmware_config.get("limits", {}), max_stall_s=MAX_STALL_BOUNDS_S[1])
        return dataclasses.replace(base, brick=Brick(single_stall_s=value / 1000.0, single_stall_at_s=PUSH_AT_S),
                                   firmware_config=dict(base.firmware_config, limits=limits))
    if key == "gyro_freeze":
        return dataclasses.replace(base, brick=Brick(gyro_freeze_s=value / 1000.0, gyro_freeze_interval_s=FREEZE_INTERVAL_S))
    raise KeyError(key)


def balances(run, floor_rad=0.0):
    """Completed with link 1's lean from the vertical within 30 degrees, ending below 0.1 rad
    (floor_rad: floor_angle_rad of the run's scenario)."""
    from hostsim.sim.metrics import UPRIGHT_LIMIT_RAD
    th1 = np.abs(run.x[:, 2] - floor_rad)
    return bool(run.completed and np.all(th1 < UPRIGHT_LIMIT_RAD) and th1[-1] < FINAL_TH1_RAD)


def _gains(path):
    return gains_document(path, False)


def _run(sc, gains_path, sysfs=None, keep_rows=False):
    """sysfs: through the fake EV3 tree (None: when the brick's effects need it, e.g. a stall)."""
    from hostsim.sim.firmware_run import run_firmware
    sysfs = sc.brick.needs_sysfs if sysfs is None else sysfs
    return run_firmware(sc, gains_doc=_gains(gains_path), sysfs=sysfs, keep_rows=keep_rows)


def bisect_margin(task):
    """Worker: -> row with the largest balancing value of one effect and sign for one gains file."""
    label, gains_path, base, m, sign, tol = task
    t0 = time.perf_counter()
    ts_s = _gains(gains_path)["ts_s"]
    trials = []

    from hostsim.sim.scenario import floor_angle_rad

    def ok(value):
        sc = margin_scenario(base, m.key, sign * value, ts_s)
        r = balances(_run(sc, gains_path), floor_angle_rad(sc))
        trials.append([value, r])
        return r

    if not ok(0.0):
        best, beyond = None, False         # it does not balance even without the effect
    elif ok(m.hi):
        best, beyond = m.hi, True
    else:
        lo, hi = 0.0, m.hi
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        best, beyond = lo, False
    return {"gains": label, "effect": m.key, "sign": sign, "margin": best, "at_least": beyond, "tol": tol,
            "trials": trials, "wall_s": time.perf_counter() - t0}


def ablation_run(task):
    """Worker: the realistic brick with one group of effects off (group), or only it on
    ("only GROUP"), or all on (None) or "all off"; one seed; the overrun stop lifted or not
    -> a row."""
    from hostsim.sim.scenario import Brick
    label, gains_path, base, group, seed, lifted = task
    brick = base.brick
    if group == "all off":
        brick = Brick()
    elif group is not None and group.startswith("only "):
        brick = Brick(**{f: getattr(brick, f) for f in dict(GROUPS)[group[len("only "):]]})
    elif group is not None:
        fields = dict(GROUPS)[group]
        brick = dataclasses.replace(brick, **{f: getattr(Brick(), f) for f in fields})
    sc = dataclasses.replace(base, brick=brick, seed=seed)
    if lifted:
        sc = dataclasses.replace(sc, firmware_config=dict(sc.firmware_config,
                                                          limits=OVERRUN_LIMIT_LIFTED))
    t0 = time.perf_counter()
    run = _run(sc, gains_path, sysfs=brick.needs_sysfs, keep_rows=True)
    return dict(run_summary(run), gains=label, off=group or "none (all on)", seed=seed, lifted=lifted,
                wall_s=time.perf_counter() - t0)


def aggregate(rows):
    """Ablation rows of one configuration over its seeds -> one row (means; balances as k/n)."""
    out = dict(rows[0])
    n = len(rows)
    out["seeds"] = [r["seed"] for r in rows]
    out["balanced"] = sum(r["balances"] for r in rows)
    out["runs"] = n
    out["stop_reasons"] = sorted({r["stop_reason"] for r in rows if not r["completed"]})
    for k in ("t_end_s", "final_abs_d_m", "rms_th1_after_2s_rad", "saturated_fraction", "overrun_fraction"):
        vals = [r[k] for r in rows if r[k] is not None]
        out[k] = float(np.mean(vals)) if vals else None
    out["peak_abs_th1_rad"] = max(r["peak_abs_th_rad"][0] for r in rows)
    return out


def run_summary(run):
    """What the report says of a run of the realistic brick (JSON-ready)."""
    from hostsim.sim.metrics import TRANSIENT_S
    t, x = run.t_s, run.x
    flags = run.flags[np.isfinite(run.flags)].astype(int) if run.flags is not None else np.zeros(0, int)
    later = t >= min(TRANSIENT_S, t[-1])
    return {
        "balances": balances(run), "completed": bool(run.completed), "stop_reason": run.stop_reason,
        "t_end_s": float(t[-1]), "final_abs_d_m": float(np.max(np.abs(x[-1, :2] - run.d_origin_m))),
        "peak_abs_th_rad": [float(v) for v in np.max(np.abs(x[:, 2:5]), axis=0)],
        "rms_th1_after_2s_rad": float(np.sqrt(np.mean(x[later, 2] ** 2))),
        "saturated_fraction": float(np.mean((flags & 15) != 0)) if len(flags) else None,
        "overrun_fraction": float(np.mean((flags & 16) != 0)) if len(flags) else None,
    }


def _variants(gains_paths):
    out = []
    for path in gains_paths:
        path = path if os.path.isabs(path) else os.path.join(REPO_ROOT, path)
        out.append((os.path.splitext(os.path.basename(path))[0], path))
    return out


def run_margins(gains_paths=DEFAULT_GAINS, coarse=False, ablation_gains=None, jobs=None, seeds=1, effects=None,
                duration_s=None):
    """-> {"margins": [rows], "ablation": [rows], "_meta": {...}}. ablation_gains: the gains
    files of the ablation (None: gains_paths; (): none); effects: keys of MARGINS (None: all);
    duration_s: other than the scenario's 30 s (for quick looks and tests only)."""
    from hostsim.sim.parallel import default_jobs, run_tasks
    from hostsim.sim.scenario import Brick, load_scenario

    realistic = load_scenario(BASE_SCENARIO)
    if duration_s is not None:
        realistic = dataclasses.replace(realistic, duration_s=float(duration_s))
    ideal = dataclasses.replace(realistic, brick=Brick())
    jobs = default_jobs() if jobs is None else jobs
    t0 = time.perf_counter()
    variants = _variants(gains_paths)
    tasks = [(label, path, ideal, m, sign, m.tol * (COARSE if coarse else 1.0))
             for label, path in variants for m in MARGINS for sign in m.signs if effects is None or m.key in effects]
    out = {"margins": run_tasks(bisect_margin, tasks, jobs=jobs, desc="margins", warm=warm_models)}
    ablation = _variants(gains_paths if ablation_gains is None else ablation_gains)
    if ablation:
        groups = [None] + [g for g, _ in GROUPS] + ["all off"] + ["only " + g for g, _ in GROUPS]
        seed_list = [realistic.seed + i for i in range(seeds)]
        tasks = [(label, path, realistic, None, seed, False) for label, path in ablation for seed in seed_list]
        tasks += [(label, path, realistic, g, seed, True) for label, path in ablation for g in groups
                  for seed in seed_list]
        rows = run_tasks(ablation_run, tasks, jobs=jobs, desc="ablation")
        keys = []
        for r in rows:
            if (r["gains"], r["off"], r["lifted"]) not in keys:
                keys.append((r["gains"], r["off"], r["lifted"]))
        out["ablation"] = [aggregate([r for r in rows if (r["gains"], r["off"], r["lifted"]) == key]) for key in keys]
    push_bound = push_bound_n_s() if effects is None or "push" in effects else None
    out["_meta"] = {"duration_s": realistic.duration_s, "push_bound_n_s": push_bound, "coarse": coarse, "jobs": jobs, "seeds": seeds,
                    "overrun_limit_lifted": OVERRUN_LIMIT_LIFTED,
                    "wall_s": time.perf_counter() - t0, "push_at_s": PUSH_AT_S,
                    "freeze_interval_s": FREEZE_INTERVAL_S, "margins": [dataclasses.asdict(m) for m in MARGINS]}
    return out


def push_bound_n_s():
    """The largest push on link 3 any law within u_max recovers on the study's plant (N s, the
    LP's recoverable bound, either direction)."""
    from hostsim.studies.push_limit import load_design, max_push
    return max_push(load_design(os.path.join(REPO_ROOT, PUSH_BOUND_GAINS)), PUSH_BOUND_HORIZON_S, "recover")[0]


def margin_cells(res, label):
    """{effect key: text} of one gains file's margins (the smaller sign where there are two; the
    push beside its LP bound)."""
    cells = {}
    for m in MARGINS:
        rows = [r for r in res["margins"] if r["gains"] == label and r["effect"] == m.key]
        if not rows:
            cells[m.key] = "-"
            continue
        if any(r["margin"] is None for r in rows):
            cells[m.key] = "fails without it"
            continue
        worst = min(rows, key=lambda r: r["margin"])
        # three significant digits: a bisection's points (32.8125) claim more than its tolerance
        text = ("%s%.3g" % (">= " if worst["at_least"] else "", worst["margin"]))
        if len(rows) > 1:
            text += " (%s)" % ", ".join("%s%.3g" % ("+" if r["sign"] > 0 else "-", r["margin"])
                                        for r in sorted(rows, key=lambda r: -r["sign"]))
        bound = res.get("_meta", {}).get("push_bound_n_s")
        if m.key == "push" and bound:
            text += "; %.0f %% of the LP bound %.3f" % (100 * worst["margin"] / bound, bound)
        cells[m.key] = text
    return cells


def margin_table(res, markdown=False):
    labels = sorted({r["gains"] for r in res["margins"]})
    head = ["effect (unit)", "realistic brick"] + ["largest balancing, %s gains" % l for l in labels]
    rows = []
    cells = {l: margin_cells(res, l) for l in labels}
    for m in MARGINS:
        rows.append(["%s (%s)" % (m.label, m.unit), m.realistic] + [cells[l][m.key] for l in labels])
    return _table(head, rows, markdown)


def ablation_table(res, markdown=False):
    head = ["gains", "overrun stop", "effects", "balanced", "stopped by", "t end s", "|d| end m",
            "peak |th1| rad", "rms th1 rad", "sat %", "overrun %"]
    rows = []
    for r in ranked_ablation(res):
        rows.append([r["gains"], "lifted" if r["lifted"] else "as shipped", _what(r["off"]), "%d/%d" % (r["balanced"], r["runs"]),
                     ", ".join(r["stop_reasons"]) or "-", "%.1f" % r["t_end_s"], "%.3f" % r["final_abs_d_m"],
                     "%.3f" % r["peak_abs_th1_rad"], "%.4f" % r["rms_th1_after_2s_rad"],
                     "-" if r["saturated_fraction"] is None else "%.1f" % (100 * r["saturated_fraction"]),
                     "-" if r["overrun_fraction"] is None else "%.1f" % (100 * r["overrun_fraction"])])
    return _table(head, rows, markdown)


def _what(off):
    if off.startswith("none"):
        return "all on"
    if off == "all off" or off.startswith("only "):
        return off
    return "all but " + off


def ranked_ablation(res):
    """Per gains file: the realistic brick as shipped, then (overrun stop lifted) all on, each
    effect off with the one whose removal helps most first (more seeds balancing, a longer
    run, less roll), then all off."""
    out = []
    for label in sorted({r["gains"] for r in res.get("ablation", [])}):
        rows = [r for r in res["ablation"] if r["gains"] == label]
        first = [r for r in rows if not r["lifted"]] + [r for r in rows if r["lifted"] and r["off"].startswith("none")]
        last = [r for r in rows if r["off"] == "all off"]
        alone = [r for r in rows if r["off"].startswith("only ")]
        middle = [r for r in rows if r not in first and r not in last and r not in alone]
        middle.sort(key=_helps_most)
        # alone: the costliest (least balanced, shortest, most roll) first
        alone.sort(key=lambda r: tuple(-v for v in _helps_most(r)))
        out += first + middle + last + alone
    return out


def _helps_most(r):
    return (-r["balanced"], -round(r["t_end_s"], 1), r["final_abs_d_m"])


def costliest(res, label):
    """The effects ranked by what each costs alone (overrun stop lifted): the one that spoils
    the ideal brick most first (fewest seeds balancing, shortest run, most roll). The
    all-but-one rows can hide it when two effects each suffice to spoil the run."""
    alone = [r for r in ranked_ablation(res) if r["gains"] == label and r["lifted"] and r["off"].startswith("only ")]
    return [r["off"][len("only "):] for r in alone]


def _table(head, rows, markdown):
    if markdown:
        out = ["| " + " | ".join(h.replace("|", "\\|") for h in head) + " |", "|" + "---|" * len(head)]
        out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
        return "\n".join(out)
    widths = [max(len(str(c)) for c in col) for col in zip(head, *rows)]
    fmt = "  ".join("%%-%ds" % w for w in widths)
    return "\n".join(fmt % tuple(r) for r in [head] + rows)


def write(res, out):
    from hostsim.studies import plots
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "margins.json"), "w") as f:
        json.dump(res, f, indent=1, sort_keys=True)
    return plots.margins_figure(res, os.path.join(out, "margins.png"), MARGINS)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("margins"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--gains", nargs="+", default=list(DEFAULT_GAINS),
                    help="gains files (default gains/paper.json gains/physical.json)")
    ap.add_argument("--coarse", action="store_true", help="tolerances x%g (what make sim runs)" % COARSE)
    ap.add_argument("--ablation-gains", nargs="+", default=None,
                    help="gains files of the ablation (default: those of --gains)")
    ap.add_argument("--no-ablation", action="store_true", help="skip the realistic brick with each effect off")
    ap.add_argument("--seeds", type=int, default=1, help="seeds per ablation run (default 1)")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    ap.add_argument("--out", default=out_dir("margins"), help="output directory (default out/margins)")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error("--seeds must be at least 1")
    res = run_margins(args.gains, args.coarse, () if args.no_ablation else args.ablation_gains, args.jobs, args.seeds)
    fig = write(res, args.out)
    print("Margins: the largest value of each effect alone at which the robot still balances %g s" %
          res["_meta"]["duration_s"])
    print(margin_table(res))
    if res.get("ablation"):
        print()
        print("The realistic brick: as shipped, then with the overrun stop lifted and each effect off in turn "
              "(costliest first)")
        print(ablation_table(res))
    print("wrote %s and %s (%.0f s)" % (os.path.join(args.out, "margins.json"), os.path.join(args.out, fig),
                                        res["_meta"]["wall_s"]))
    return 0
