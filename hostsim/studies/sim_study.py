"""``python -m hostsim sim`` (``make sim``): the paper's experiments, robustness, the report.

Runs scenarios/section7, section8, appendix_d (the paper's), section8_physical (our robot's
gains on the physical model) and brick_realistic (the firmware on an EV3 as unkind as the real
one) in all their modes, a short region-of-attraction study, a Monte Carlo on today's
simulated robot and one on the realistic brick, the margins of each brick effect alone and
what each costs (hostsim.studies.margins, coarse), writes everything under out/sim/ (per
scenario: metrics.json, figures, runs.npz; robustness/; report.md) and prints the summary
tables. Builds a missing gains file first (python -m hostsim gains). Exit status 1 if a
scenario's expectations fail.
"""
import argparse
import os
import shutil
import sys
import time

import hostsim
from hostsim.paths import REPO_ROOT, out_dir

SCENARIOS = ("section7", "section7_governed", "section8", "appendix_d", "section8_physical", "brick_realistic")
# Issue 22: a payload on link 3 and sloped floors on the realistic brick, reported in one
# compact table (load_table) rather than a section each.
LOAD_SCENARIOS = ("payload_100g", "payload_put_on", "slope_up_5deg", "slope_down_5deg", "ramp")
# Issue 21: driving courses on the realistic brick, one table and a plan view each.
DRIVE_SCENARIOS = ("drive_straight", "drive_square", "drive_eight")
ABLATION_GAINS = ("gains/physical.json",)     # what make deploy ships
GAINS = ("paper", "physical")
# the options that change what the docs pages' generated blocks show (hostsim.studies.sim_docs)
DOCS_DEFAULTS = ("scenarios", "drive_scenarios", "load_scenarios", "device", "mc_runs", "mc_brick_runs",
                 "mc_duration", "roa_tol", "kw0", "no_robustness", "no_margins", "host_estimator")


def ensure_gains(say):
    from hostsim.model import gains
    for name in GAINS:
        path = os.path.join(gains.DEFAULT_OUT_DIR, name + ".json")
        if not os.path.exists(path):
            say("%s is missing: generating it (python -m hostsim gains --variant %s)" % (os.path.relpath(path, REPO_ROOT), name))
            if gains.main(["--variant", name]) != 0:
                raise SystemExit("could not generate %s" % path)


def firmware_note(docs, mc):
    """What the firmware-in-the-loop results say about the firmware as it is."""
    from tipbot_fw.config import defaults
    estimator = defaults()["estimator"]
    lines = ["The firmware runs its default estimator, %s; the linear and nonlinear modes run the paper's law "
             "(the Section 6 detector fed the exact state)." % (
                 "the Kalman filter (tipbot_fw.cores.kalman: it measures what the sensors measure and estimates the "
                 "wheels' input disturbances and the gyro bias)" if estimator == "kalman" else
                 "the paper's detector on the firmware's signal chain")]
    fell = [(d["scenario"], l) for d in docs for l, m in d["runs"].items()
            if l.startswith("firmware/") and not m["upright"]]
    if fell:
        lines.append("With the shipped gains the firmware in the loop did not stay up in %d of the scenario runs "
                     "(%s)." % (len(fell), ", ".join("%s `%s`" % f for f in fell)))
    if mc:
        rates = {k: v["summary"]["success_rate"] for k, v in mc.items() if not k.startswith("_")}
        lines.append("Monte Carlo success: %s." % ", ".join("%s %.0f %%" % (k, 100 * v) for k, v in rates.items()))
    return " ".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("sim"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=out_dir("sim"), help="output directory (default out/sim)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS),
                    help="scenario names or files (default: %s)" % " ".join(SCENARIOS))
    ap.add_argument("--drive-scenarios", nargs="*", default=list(DRIVE_SCENARIOS),
                    help="driving courses, one table and a plan view each (default: %s)" % " ".join(DRIVE_SCENARIOS))
    ap.add_argument("--load-scenarios", nargs="*", default=list(LOAD_SCENARIOS),
                    help="payload and slope scenarios, one compact table (default: %s)" % " ".join(LOAD_SCENARIOS))
    ap.add_argument("--device", choices=("sysfs", "memory"), default="sysfs",
                    help="firmware device layer for the scenarios (default: the fake EV3 sysfs tree)")
    ap.add_argument("--mc-runs", type=int, default=40, help="Monte Carlo runs per gains file (default 40; "
                    "python -m hostsim montecarlo for the full study)")
    ap.add_argument("--mc-brick-runs", type=int, default=20, help="Monte Carlo runs per gains file on the realistic "
                    "brick (default 20; python -m hostsim montecarlo --brick for more)")
    ap.add_argument("--mc-duration", type=float, default=10.0, help="seconds per Monte Carlo run (default 10)")
    ap.add_argument("--roa-tol", type=float, default=0.02, help="region of attraction bisection resolution in rad (default 0.02)")
    ap.add_argument("--kw0", action="store_true", help="also run the robustness with K_w = 0 (a diagnosis: "
                    "what the disturbance compensation costs or buys in the firmware)")
    ap.add_argument("--no-robustness", action="store_true", help="skip the region of attraction, the Monte Carlos "
                    "and the margins")
    ap.add_argument("--no-margins", action="store_true", help="skip the margins and the effects' costs")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    ap.add_argument("--host-estimator", choices=("detector", "kalman"), default="detector",
                    help="the linear and nonlinear runs' estimator: the paper's detector (default, the paper's "
                         "simulation) or the firmware's default, the Kalman filter, to compare the firmware's "
                         "runs with it (make sim SIM_ARGS='--host-estimator kalman')")
    ap.add_argument("--no-docs", action="store_true", help="leave the docs pages' generated blocks as they are "
                    "(only the whole default study writes them, with docs/data/sim.json)")
    ap.add_argument("--docs-from-saved", action="store_true", help="run nothing: write docs/data/sim.json and the "
                    "docs pages' generated blocks from the whole default study saved in --out (after a block was added)")
    args = ap.parse_args(argv)
    if args.docs_from_saved:
        from hostsim.studies import docblocks
        from hostsim.studies import sim_docs
        payload, date = sim_docs.payload_from_dir(args.out, SCENARIOS, LOAD_SCENARIOS, DRIVE_SCENARIOS)
        docblocks.refresh("sim", payload, date=date)
        return 0
    # the docs pages show the whole default study: a partial or different one leaves them alone
    args.docs = not args.no_docs and all(getattr(args, k) == ap.get_default(k) for k in DOCS_DEFAULTS)
    final = args.out
    # the new report is made beside the old one and swapped in at the end: an interrupted or
    # failed study leaves the previous report whole
    args.out = os.path.join(os.path.dirname(os.path.abspath(final)), "." + os.path.basename(final) + ".new")
    shutil.rmtree(args.out, ignore_errors=True)
    try:
        code = _study(args, final)
    except KeyboardInterrupt:
        shutil.rmtree(args.out, ignore_errors=True)
        print("sim: interrupted: nothing new written; %s keeps the previous report" % final, file=sys.stderr)
        return 130
    except BaseException:
        shutil.rmtree(args.out, ignore_errors=True)
        raise
    return code


def _swap_in(new, final):
    """Replace the directory ``final`` by ``new`` (the old one removed after the swap)."""
    old = new[:-len(".new")] + ".old"
    shutil.rmtree(old, ignore_errors=True)
    if os.path.exists(final):
        os.rename(final, old)
    os.rename(new, final)
    shutil.rmtree(old, ignore_errors=True)


def _study(args, final):
    from hostsim.studies import margins
    from hostsim.studies import montecarlo
    from hostsim.studies import report
    from hostsim.studies import roa
    from hostsim.studies import runner
    from hostsim.sim.scenario import load_scenario

    def say(msg):
        print(msg, file=sys.stderr, flush=True)

    t_start = time.perf_counter()
    ensure_gains(say)
    os.makedirs(args.out, exist_ok=True)
    def run_all(names):
        docs = []
        for name in names:
            sc = load_scenario(name)
            say("scenario %s" % name)
            docs.append(runner.run_and_write(sc, os.path.join(args.out, sc.name), sysfs=args.device == "sysfs",
                                             say=say, host_estimator=args.host_estimator))
        return docs

    docs = run_all(args.scenarios)
    ok = all(doc["expect_ok"] for doc in docs)
    load_docs = run_all(args.load_scenarios)
    drive_docs = run_all(args.drive_scenarios)
    roa_res = mc_res = mc_brick = margins_res = None
    if not args.no_robustness:
        rdir = os.path.join(args.out, "robustness")
        say("region of attraction")
        roa_res = roa.run_roa(tol=args.roa_tol, kw0=args.kw0, jobs=args.jobs, kw0_modes=("firmware",))
        roa.write(roa_res, rdir)
        say("Monte Carlo")
        mc_res = montecarlo.run_montecarlo(args.mc_runs, args.mc_duration, kw0=args.kw0, jobs=args.jobs)
        montecarlo.write(mc_res, rdir)
        say("Monte Carlo on the realistic brick")
        mc_brick = montecarlo.run_montecarlo(args.mc_brick_runs, args.mc_duration, jobs=args.jobs,
                                             base=montecarlo.BRICK_SCENARIO, desc="Monte Carlo (brick)")
        montecarlo.write(mc_brick, rdir, "montecarlo_brick")
        if not args.no_margins:
            say("margins (coarse) and what each effect costs")
            margins_res = margins.run_margins(coarse=True, ablation_gains=ABLATION_GAINS, jobs=args.jobs)
            margins.write(margins_res, rdir)
    note = firmware_note(docs, mc_res)
    notes = []
    if drive_docs:
        notes.append("## Driving (issue 21)\n\nCourses on the realistic brick with `physical` gains, the firmware "
                     "following its drive plan; tracking measured on the simulated robot's true path against the "
                     "commanded one (the plan view in each scenario's directory).\n\n" + report.drive_table(drive_docs) + "\n")
    if load_docs:
        notes.append("## Payloads on link 3 and slopes (issue 22)\n\nThe realistic brick with `physical` gains; "
                     "each scenario's files under its own directory.\n\n" + report.load_table(load_docs) + "\n")
    report.write_report(args.out, docs, roa_res, mc_res, extra_notes=notes, firmware_note=note,
                        mc_brick=mc_brick, margins=margins_res)
    _swap_in(args.out, final)
    path = os.path.join(final, "report.md")
    if args.docs:
        from hostsim.studies import docblocks
        from hostsim.studies import sim_docs
        docblocks.refresh("sim", sim_docs.payload(docs, load_docs, drive_docs, roa_res, mc_res, mc_brick, margins_res),
                          say=say)
    else:
        say("the docs pages' generated blocks left as they are (%s)" % (
            "--no-docs" if args.no_docs else "not the whole default study"))
    for doc in docs:
        print(runner.format_summary(doc))
        print()
    print("(%s)" % runner.SUMMARY_NOTE)
    print()
    tables = [
        ("Driving courses (realistic brick)", drive_docs and report.drive_table(drive_docs)),
        ("Payloads on link 3 and slopes (realistic brick)", load_docs and report.load_table(load_docs)),
        ("Region of attraction (largest recovered initial angle)", roa_res and roa.format_table(roa_res)),
        ("Monte Carlo (firmware in the loop, physical model)", mc_res and montecarlo.format_table(mc_res)),
        ("Monte Carlo on the realistic brick", mc_brick and montecarlo.format_table(mc_brick)),
        ("Margins: the largest value of each effect alone at which the robot still balances (coarse)",
         margins_res and margins.margin_table(margins_res)),
        ("The realistic brick: as shipped, then with the overrun stop lifted",
         margins_res and margins.ablation_table(margins_res)),
    ]
    for title, table in tables:
        if table:
            print(title)
            print(table)
            print()
    if note:
        print(note)
        print()
    print("wrote %s (%.0f s)" % (os.path.relpath(path, os.getcwd()) if path.startswith(os.getcwd()) else path,
                                 time.perf_counter() - t_start))
    return 0 if ok else 1

