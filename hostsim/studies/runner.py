"""Run a scenario in its modes and controllers, compute metrics, write metrics.json and plots.

``python -m hostsim run SCENARIO --out DIR`` (hostsim.__main__) is a thin wrapper around
``run_and_write``. Run labels are ``<mode>/<controller>`` (``linear/optimal``,
``firmware/pd``, ...).
"""
import dataclasses
import json
import os
import time

import hostsim
import numpy as np

from hostsim.sim import metrics as metrics_mod
from hostsim.sim.metrics import STATE_UNIT_GROUPS
from hostsim.sim.firmware_build import pd_gains_document
from hostsim.sim.firmware_run import run_firmware
from hostsim.sim.linear_sim import ESTIMATORS, simulate_linear, simulate_nonlinear
from hostsim.model.pd import pd_for_gains
from tipbot_fw.gains import load_gains, load_gains_document


def run_label(label, host_estimator):
    """A run's label (mode/controller) with the linear and nonlinear modes' estimator when it is
    not the paper's detector: nonlinear-kalman/optimal."""
    mode, controller = label.split("/")
    if mode == "firmware" or host_estimator == "detector":
        return label
    return "%s-%s/%s" % (mode, host_estimator, controller)


def run_scenario(sc, modes=None, sysfs=True, say=None, host_estimator="detector"):
    """-> (Gains, {label: RunResult}) for every mode x controller of the scenario.
    host_estimator: the linear and nonlinear modes' ("detector", the paper's; "kalman", the
    firmware's default: their labels then read linear-kalman/..., nonlinear-kalman/...)."""
    gs = load_gains(sc.gains)
    runs = {}
    for controller in sc.controllers:
        k_pd_file = np.array(pd_for_gains(sc.gains)["K"]) if controller == "pd" else None
        # x_file = S x_SI, so a gain on the file's state is K_file S on the SI one
        k_pd = None if k_pd_file is None else k_pd_file * gs.state_scale[None, :]
        for mode in modes or sc.modes:
            label = run_label("%s/%s" % (mode, controller), host_estimator)
            t0 = time.perf_counter()
            if mode == "linear":
                run = simulate_linear(gs, sc, k_pd, estimator=host_estimator)
            elif mode == "nonlinear":
                run = simulate_nonlinear(gs, sc, k_pd, estimator=host_estimator)
            else:
                doc = None if k_pd_file is None else pd_gains_document(load_gains_document(sc.gains)[0], k_pd_file)
                # the brick's timing and mode writes act through the fake EV3 tree only
                run = run_firmware(sc, gains_doc=doc, sysfs=sysfs or sc.brick.needs_sysfs)
            run = runs[label] = dataclasses.replace(run, wall_s=time.perf_counter() - t0)
            if say:
                say("  %-20s %6.2f s simulated in %5.2f s" % (label, run.t_s[-1], run.wall_s))
    return gs, runs


def ideal_metrics(sc, gs):
    """Metrics of the perfect-measurement run of the scenario (nonlinear plant, true state and
    disturbance fed to the law): the reference the firmware's inputs are judged against."""
    return metrics_mod.compute(simulate_nonlinear(gs, sc, ideal=True), sc, gs.u_max_v)


def scenario_metrics(sc, gs, runs):
    out = {}
    ideal = ideal_metrics(sc, gs) if any(label.startswith("firmware/") for label in runs) else None
    for label, run in runs.items():
        m = metrics_mod.compute(run, sc, gs.u_max_v)
        if ideal is not None:
            m = metrics_mod.with_ideal(m, ideal)
        m["wall_s"] = round(run.wall_s, 3)
        m["real_time_factor"] = round(m["duration_s"] / run.wall_s, 2) if run.wall_s > 0 else None
        if run.exit_code is not None:
            m["firmware_exit_code"] = run.exit_code
        out[label] = m
    return out


def run_and_write(sc, out_dir, modes=None, sysfs=True, plots=True, say=None, host_estimator="detector"):
    """Run, write DIR/metrics.json (+ PNGs and runs.npz); -> the metrics document."""
    os.makedirs(out_dir, exist_ok=True)
    gs, runs = run_scenario(sc, modes, sysfs, say, host_estimator)
    per_run = scenario_metrics(sc, gs, runs)
    expect = {run_label(label, host_estimator): bounds for label, bounds in sc.expect.items()}
    expect_report, ok = metrics_mod.check_expectations(per_run, expect)
    doc = {
        "scenario": sc.name,
        "description": sc.description,
        "gains": os.path.basename(sc.gains),
        "plant_variant": sc.plant_variant,
        "plant_method": sc.plant_method,
        "duration_s": sc.duration_s,
        "u_max_v": gs.u_max_v,
        "firmware_device": "fake EV3 sysfs" if sysfs or sc.brick.needs_sysfs else "in-memory",
        "brick": dataclasses.asdict(sc.brick),
        "runs": per_run,
        "expect": expect_report,
        "expect_ok": ok,
        # What the law asks for at the true initial state: the paper's Section 7 claim.
        "k_x0_v": [float(v) for v in (-gs.K @ np.asarray(sc.x0_si))[[0, 1, 3, 4]]],
    }
    if "pd" in sc.controllers:
        doc["pd"] = pd_for_gains(sc.gains)
    with open(os.path.join(out_dir, "metrics.json"), "w") as f:
        json.dump(doc, f, indent=1, sort_keys=True)
    np.savez_compressed(os.path.join(out_dir, "runs.npz"), **_flatten(runs))
    if plots:
        from hostsim.studies import plots as plots_mod
        doc["plots"] = plots_mod.scenario_plots(sc, runs, gs.u_max_v, out_dir)
        with open(os.path.join(out_dir, "metrics.json"), "w") as f:
            json.dump(doc, f, indent=1, sort_keys=True)
    return doc


def _flatten(runs):
    return {"%s/%s" % (label, key): value for label, run in runs.items() for key, value in run.arrays().items()}


SUMMARY_COLUMNS = (
    ("run", "%-18s"), ("up", "%-11s"), ("|th1| rad", "%9s"), ("|th2| rad", "%9s"), ("|th3| rad", "%9s"),
    ("|u| V", "%6s"), ("demand V", "%8s"), ("sat %", "%5s"), ("settle s", "%8s"), ("|d| end m", "%9s"),
) + tuple(("est %s" % unit, "%9s") for unit, _ in STATE_UNIT_GROUPS)
SUMMARY_NOTE = ("|th| and |u|: peaks (|u|: the volts the motors got, which on the firmware's runs can pass "
                "u_max by half a duty step, 0.04 V, plus what the battery rose since its last reading, once a "
                "second); demand: the largest input asked for before saturation; |d| end: distance "
                "from the wheel origin at the end; est <unit>: the largest |estimate - x| over the last quarter of "
                "the run, of the states in that unit (d; th1-3; d'; th1-3'): the firmware's Kalman filter's x^, "
                "the detector's x~ in the linear and nonlinear runs")


def summary_rows(doc):
    rows = []
    for label, m in doc["runs"].items():
        th = m["peak_abs_th_rad"]
        demand = m.get("peak_abs_u_unsat_v")
        est = m.get("final_est_error_by_unit") or {}
        rows.append([
            "%s" % label, "yes" if m["upright"] else (m.get("stop_reason") or "fell").upper(),
            "%.3f" % th[0], "%.3f" % th[1], "%.3f" % th[2], "%.2f" % max(m["peak_abs_u_v"]),
            "-" if demand is None else "%.1f" % max(demand), "%.1f" % (100 * m["saturated_fraction"]),
            "-" if m["settle_time_s"] is None else "%.2f" % m["settle_time_s"],
            "%.3f" % m["final_abs_d_m"],
        ] + ["-" if est.get(unit) is None else "%.1e" % est[unit] for unit, _ in STATE_UNIT_GROUPS])
    return rows


def format_summary(doc):
    head = " ".join(fmt % name for name, fmt in SUMMARY_COLUMNS)
    lines = ["%s (%s gains, %s plant, %g s): %s" % (doc["scenario"], doc["gains"], doc["plant_variant"],
                                                    doc["duration_s"], doc["description"]), "  " + head]
    for row in summary_rows(doc):
        lines.append("  " + " ".join(fmt % v for (_, fmt), v in zip(SUMMARY_COLUMNS, row)))
    for label, checks in doc["expect"].items():
        for key, c in checks.items():
            if not c["ok"]:
                lines.append("  EXPECTATION FAILED: %s %s = %s (bound %s)" % (label, key, c["value"], c["bound"]))
    return "\n".join(lines)


def main(argv=None):
    import argparse
    import sys

    from hostsim.errors import TipbotError
    from hostsim.paths import out_dir
    from hostsim.sim.scenario import MODES, load_scenario

    ap = argparse.ArgumentParser(prog=hostsim.command("run"), description="Run one scenario file.")
    ap.add_argument("scenario", help="scenario JSON file, or a name under scenarios/")
    ap.add_argument("--out", help="output directory (default out/run/<scenario>)")
    ap.add_argument("--modes", help="comma-separated subset of the scenario's modes (%s)" % ", ".join(MODES))
    ap.add_argument("--device", choices=("sysfs", "memory"), default="sysfs",
                    help="firmware device layer: the fake EV3 sysfs tree (default) or in-memory")
    ap.add_argument("--no-plots", action="store_true", help="write metrics.json and runs.npz only")
    ap.add_argument("--host-estimator", choices=ESTIMATORS, default="detector",
                    help="the estimator of the linear and nonlinear modes: the paper's detector (default) or the "
                         "firmware's default, the Kalman filter (its runs labelled linear-kalman/..., nonlinear-kalman/...)")
    args = ap.parse_args(argv)
    try:
        sc = load_scenario(args.scenario)
        modes = None
        if args.modes:
            modes = [m.strip() for m in args.modes.split(",") if m.strip()]
            bad = [m for m in modes if m not in sc.modes]
            if bad:
                raise TipbotError("--modes: %r is not a mode of scenario %s (%s)" % (bad[0], sc.name, ", ".join(sc.modes)))
        out = args.out or out_dir("run", sc.name)
        doc = run_and_write(sc, out, modes, sysfs=args.device == "sysfs", plots=not args.no_plots,
                            say=lambda m: print(m, file=sys.stderr), host_estimator=args.host_estimator)
    except TipbotError as exc:
        print("error: %s" % exc, file=sys.stderr)
        return 2
    print(format_summary(doc))
    print("(%s)" % SUMMARY_NOTE)
    print("wrote %s" % os.path.join(out, "metrics.json"))
    return 0 if doc["expect_ok"] else 1
