"""Region of attraction: the largest initial angle the controller recovers from, by bisection.

``python -m hostsim roa [--gains FILE ...] [--modes nonlinear,firmware] [--tol 0.01]
[--kw0] [--jobs N] [--out DIR]``

For each gains file, each of th1, th2, th3 and each sign, the robot is released from rest
with only that angle nonzero (scenarios/roa_base.json: the physical plant, 5 s) and is
"recovered" when the run completes, |th1| stays below 30 degrees and ends below
``RECOVERED_TH1_RAD``, and |th2|, |th3| end below ``RECOVERED_TH23_RAD``. Bisection on the
angle's magnitude between 0 and the firmware's stop limit for that angle (limits.th1_rad =
0.6, limits.th2_rad/th3_rad = 1.2 rad by default: beyond them the firmware stops the
motors whatever the controller could do), assuming recovery is monotonic in the magnitude.

Modes: ``nonlinear`` (the host-side law, ideal measurement, estimate starting at the true
state) and ``firmware`` (the firmware in the loop, told the start pose as an operator
would configure it). The difference between the two is what the signal chain costs.
"""
import argparse
import dataclasses
import json
import os
import time

import hostsim
import numpy as np

from hostsim.paths import out_dir
from tipbot_fw.gains import gains_from_dict

ANGLES = {"th1": 2, "th2": 3, "th3": 4}
RECOVERED_TH1_RAD = 0.05
RECOVERED_TH23_RAD = 0.3
DEFAULT_MODES = ("nonlinear", "firmware")
DEFAULT_GAINS = ("gains/paper.json", "gains/physical.json")
BASE_SCENARIO = "roa_base"


def angle_limits():
    from tipbot_fw.config import defaults
    lim = defaults()["limits"]
    return {"th1": lim["th1_rad"], "th2": lim["th2_rad"], "th3": lim["th3_rad"]}


def recovered(run):
    from hostsim.sim.metrics import UPRIGHT_LIMIT_RAD
    x = run.x
    return bool(run.completed and np.all(np.abs(x[:, 2]) < UPRIGHT_LIMIT_RAD)
                and abs(x[-1, 2]) < RECOVERED_TH1_RAD and np.all(np.abs(x[-1, 3:5]) < RECOVERED_TH23_RAD))


def trial(base, gains_path, zero_kw, mode, angle, value):
    """One release from `angle` = value: recovered or not."""
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.linear_sim import simulate_nonlinear
    from hostsim.studies.montecarlo import gains_document

    x0 = [0.0] * 10
    x0[ANGLES[angle]] = float(value)
    sc = dataclasses.replace(base, x0_si=tuple(x0), xhat0_si=None, gains=gains_path)
    doc = gains_document(gains_path, zero_kw)
    if mode == "nonlinear":
        run = simulate_nonlinear(gains_from_dict(doc, gains_path), sc)
    elif abs(value) >= angle_limits()[angle]:
        return False    # the firmware refuses to be told a start pose at its stop limit (tipbot_fw.config)
    else:
        run = run_firmware(sc, gains_doc=doc, sysfs=False, keep_rows=False)
    return recovered(run)


def bisect(task):
    """Worker: -> row with the largest recovered magnitude for one (gains, mode, angle, sign)."""
    label, gains_path, zero_kw, base, mode, angle, sign, hi, tol = task
    t0 = time.perf_counter()
    trials = []

    def ok(mag):
        r = trial(base, gains_path, zero_kw, mode, angle, sign * mag)
        trials.append([mag, r])
        return r

    if ok(hi):
        best = hi
    elif not ok(tol):
        best = 0.0
    else:
        lo = tol
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            if ok(mid):
                lo = mid
            else:
                hi = mid
        best = lo
    return {"gains": label, "mode": mode, "angle": angle, "sign": sign, "max_recovered_rad": best,
            "limit_rad": task[7], "trials": trials, "wall_s": time.perf_counter() - t0}


def run_roa(gains_paths=DEFAULT_GAINS, modes=DEFAULT_MODES, tol=0.01, kw0=False, jobs=None, angles=tuple(ANGLES),
            base=None, duration_s=None, kw0_modes=None):
    """Bisections for every gains file x mode x angle x sign (kw0: also K_w = 0 twins, in
    kw0_modes, default the same modes)."""
    from hostsim.studies.montecarlo import variants, warm_models
    from hostsim.sim.parallel import run_tasks
    from hostsim.sim.scenario import load_scenario

    base = base or load_scenario(BASE_SCENARIO)
    if duration_s is not None:
        base = dataclasses.replace(base, duration_s=float(duration_s))
    limits = angle_limits()
    tasks = [(label, path, zk, base, mode, angle, sign, limits[angle], tol)
             for label, path, zk in variants(gains_paths, kw0)
             for mode in ((kw0_modes or modes) if zk else modes)
             for angle in angles for sign in (1, -1)]
    t0 = time.perf_counter()
    rows = run_tasks(bisect, tasks, jobs=jobs, desc="region of attraction",
                     warm=lambda: warm_models((base.plant_variant,)))
    return {"rows": rows, "wall_s": time.perf_counter() - t0, "tol_rad": tol, "duration_s": base.duration_s,
            "plant_variant": base.plant_variant}


def format_table(res):
    rows = res["rows"]
    groups = []
    for r in rows:
        if (r["gains"], r["mode"]) not in groups:
            groups.append((r["gains"], r["mode"]))
    angles = []
    for r in rows:
        if r["angle"] not in angles:
            angles.append(r["angle"])
    head = "%-18s %-10s" % ("gains", "mode") + "".join(" %15s" % ("%s -/+ rad" % a) for a in angles)
    lines = [head]
    for g, m in groups:
        cells = []
        for a in angles:
            v = {r["sign"]: r for r in rows if (r["gains"], r["mode"], r["angle"]) == (g, m, a)}
            cells.append(" %15s" % ("%.2f / %.2f%s" % (v[-1]["max_recovered_rad"], v[1]["max_recovered_rad"],
                                                       "*" if max(v[s]["max_recovered_rad"] for s in v) >= v[1]["limit_rad"] else "")))
        lines.append("%-18s %-10s" % (g, m) + "".join(cells))
    lines.append("(* = up to the firmware's stop limit; bisection to %.3f rad, %g s per release, %.1f s wall)"
                 % (res["tol_rad"], res["duration_s"], res["wall_s"]))
    return "\n".join(lines)


def write(res, out_dir):
    from hostsim.studies import plots
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "roa.json"), "w") as f:
        json.dump(res, f, indent=1, sort_keys=True)
    return plots.roa_figure(res["rows"], os.path.join(out_dir, "roa.png"))


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("roa"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--gains", nargs="+", default=list(DEFAULT_GAINS), help="gains files (default gains/paper.json gains/physical.json)")
    ap.add_argument("--modes", default=",".join(DEFAULT_MODES), help="comma-separated: nonlinear, firmware")
    ap.add_argument("--tol", type=float, default=0.01, help="bisection resolution in rad (default 0.01)")
    ap.add_argument("--kw0", action="store_true", help="also run each gains file with K_w = 0 (diagnosis)")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    ap.add_argument("--out", default=out_dir("roa"), help="output directory (default out/roa)")
    args = ap.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in DEFAULT_MODES]
    if bad or not modes:
        ap.error("--modes: choose from %s" % ", ".join(DEFAULT_MODES))
    if not args.tol > 0:
        ap.error("--tol must be positive")
    res = run_roa(args.gains, modes, args.tol, args.kw0, args.jobs)
    fig = write(res, args.out)
    print(format_table(res))
    print("wrote %s and %s" % (os.path.join(args.out, "roa.json"), os.path.join(args.out, fig)))
    return 0

