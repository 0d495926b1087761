"""``make sim``'s generated blocks in the docs pages (hostsim.studies.docblocks): what they show, from what.

``payload(...)`` keeps of the study's results what the blocks show (docs/data/sim.json, figures
to 6 significant digits); each render below makes one block from that file. The tables are
those of out/sim/report.md (hostsim.studies.report and friends), so the page and the report
say the same.
"""
# per run, the metrics the blocks read
RUN_KEYS = ("upright", "stop_reason", "completed", "duration_s", "peak_abs_th_rad", "peak_abs_u_v",
            "peak_abs_u_unsat_v", "saturated_fraction", "overrun_fraction", "settle_time_s", "final_abs_d_m",
            "final_est_error_by_unit", "rms_u_v", "ideal_rms_u_v", "rms_th1_after_transient_rad",
            "oscillation_above_1hz", "tracking", "joint_offset_rad", "equilibrium_lean_rad", "lean_from_vertical_rad")
DOC_KEYS = ("scenario", "description", "gains", "plant_variant", "duration_s")
LINES = ("th1", "th2", "th3", "wheel_speed", "u_th2", "u_th3")   # the spectral lines the blocks quote
MODES = ("linear", "nonlinear", "firmware")           # the runs' order in a table, as make sim runs them
DROP = ("trials", "wall_s", "mean_wall_s", "runs_per_s", "jobs", "draw")   # bisection trails, timings, draws


def _round(v):
    """Figures to 6 significant digits (every table prints fewer), containers walked, a dict's
    keys sorted: the same file whether the study's results come from memory or from its files."""
    if isinstance(v, float):
        return float("%.6g" % v)
    if isinstance(v, dict):
        return {k: _round(v[k]) for k in sorted(v) if k not in DROP}
    if isinstance(v, (list, tuple)):
        return [_round(x) for x in v]
    return v


def _run_order(label):
    mode, controller = label.split("/")
    return (MODES.index(mode.split("-")[0]), controller != "optimal", label)


def _doc(doc):
    runs = {}
    for label, m in sorted(doc["runs"].items(), key=lambda kv: _run_order(kv[0])):
        r = {k: m.get(k) for k in RUN_KEYS}
        osc = m.get("oscillation_above_1hz") or {}
        r["oscillation_above_1hz"] = {k: {"amplitude": osc[k]["amplitude"], "hz": osc[k]["hz"]}
                                      for k in LINES if osc.get(k)}
        runs[label] = _round(r)
    return dict(_round({k: doc[k] for k in DOC_KEYS}), runs=runs)      # the runs in their table order


def _mc(mc):
    return None if not mc else {k: (v if k.startswith("_") else {"summary": v["summary"]}) for k, v in mc.items()}


def payload(docs, load_docs, drive_docs, roa, mc, mc_brick, margins):
    """What the blocks show, JSON-ready: the scenario metrics documents (the metrics RUN_KEYS),
    the region of attraction's rows, the Monte Carlos' summaries, the margins and ablation."""
    return {
        "scenarios": [_doc(d) for d in docs], "load": [_doc(d) for d in load_docs],
        "drive": [_doc(d) for d in drive_docs],
        "roa": _round(roa and {k: roa[k] for k in ("rows", "tol_rad", "duration_s", "plant_variant")}),
        "montecarlo": _round(_mc(mc)), "montecarlo_brick": _round(_mc(mc_brick)),
        "margins": _round(margins and {"margins": margins["margins"], "ablation": margins.get("ablation", []),
                                       "_meta": {k: margins["_meta"][k] for k in ("duration_s", "coarse", "seeds",
                                                                                  "overrun_limit_lifted")}}),
    }


def payload_from_dir(out, scenarios, load, drive):
    """(payload, date) from what a whole default make sim left in out (the metrics.json of its
    scenarios, load and drive scenarios by name, robustness/*.json), dated by its report.md: a
    new block without rerunning the study (python -m hostsim sim --docs-from-saved)."""
    import datetime
    import json
    import os
    import re

    def read(*parts):
        with open(os.path.join(out, *parts), encoding="utf-8") as f:
            return json.load(f)
    docs = lambda names: [read(n, "metrics.json") for n in names]
    rob = lambda name: read("robustness", name + ".json")
    with open(os.path.join(out, "report.md"), encoding="utf-8") as f:
        date = re.search(r"\bon (\d{4}-\d{2}-\d{2})\b", f.read()).group(1)
    datetime.date.fromisoformat(date)
    return payload(docs(scenarios), docs(load), docs(drive), rob("roa"), rob("montecarlo"), rob("montecarlo_brick"),
                   rob("margins")), date


def _scenario(data, name):
    for doc in data["scenarios"]:
        if doc["scenario"] == name:
            return doc
    raise KeyError("docs/data/sim.json has no scenario %s" % name)


# ------------------------------------------------------------------------------ the blocks
def summary(data):
    from hostsim.studies.report import summary_table
    from hostsim.studies.runner import SUMMARY_NOTE
    return summary_table(data["scenarios"]) + "\n\n(" + SUMMARY_NOTE + ".)"


FIRMWARE_SCENARIOS = ("section8_physical", "section8")


def _line(m, keys, unit, scale, fmt):
    osc = m["oscillation_above_1hz"]
    there = [k for k in keys if k in osc]
    if not there:
        return "-"
    k = max(there, key=lambda k: osc[k]["amplitude"])
    return ("%s " % k if len(keys) > 1 else "") + (fmt % (scale * osc[k]["amplitude"])) + " %s at %.1f Hz" % (unit, osc[k]["hz"])


def firmware_section8(data):
    """Section 8 (50 s, a 1 V wheel disturbance), firmware in the loop: the robot's gains on the
    physical plant beside the paper's gains on the paper's plant."""
    docs = [_scenario(data, n) for n in FIRMWARE_SCENARIOS]
    runs = [d["runs"]["firmware/optimal"] for d in docs]
    rows = [
        ("saturated ticks", lambda m: "%.1f %%" % (100 * m["saturated_fraction"])),
        ("wheel input RMS / the ideal run's", lambda m: "%.3f / %.3f V = %.2f" % (
            sum(m["rms_u_v"][:2]) / 2, sum(m["ideal_rms_u_v"][:2]) / 2, sum(m["rms_u_v"][:2]) / sum(m["ideal_rms_u_v"][:2]))),
        ("joint inputs RMS", lambda m: "%.3f, %.3f V" % tuple(m["rms_u_v"][2:4])),
        ("tilt RMS after 2 s", lambda m: "%.5f rad" % m["rms_th1_after_transient_rad"]),
        ("distance from the origin at the end", lambda m: "%.1f mm" % (1000 * m["final_abs_d_m"])),
        ("strongest line above 1 Hz: links", lambda m: _line(m, ("th1", "th2", "th3"), "mrad", 1000, "%.1f")),
        ("strongest line above 1 Hz: wheel speed", lambda m: _line(m, ("wheel_speed",), "mm/s", 1000, "%.1f")),
        ("strongest line above 1 Hz: joint inputs", lambda m: _line(m, ("u_th2", "u_th3"), "V", 1, "%.3f")),
    ]
    out = ["| firmware in the loop, Section 8 | " + " | ".join(
        "`%s` gains, `%s` plant" % (d["gains"].replace(".json", ""), d["plant_variant"]) for d in docs) + " |",
           "|---|" + "---|" * len(docs)]
    out += ["| %s | %s |" % (what, " | ".join(fn(m) for m in runs)) for what, fn in rows]
    return "\n".join(out)


def roa(data):
    from hostsim.studies.report import roa_table
    r = data["roa"]
    return ("Largest initial angle (that one alone, released from rest) after which the robot is upright at %g s; "
            "bisection to %.3f rad on the `%s` model, up to the firmware's stop limits ((limit): reached).\n\n%s"
            % (r["duration_s"], r["tol_rad"], r["plant_variant"], roa_table(r)))


def _mc_block(mc, what):
    from hostsim.studies.report import mc_table
    meta = mc["_meta"]
    return "%s: %d runs of %g s per gains file, seed %d.\n\n%s" % (
        what, meta["runs_per_gains"], meta["duration_s"], meta["seed"], mc_table(mc))


def montecarlo(data):
    return _mc_block(data["montecarlo"], "Firmware in the loop on the `%s` model (in-memory device)"
                     % data["montecarlo"]["_meta"]["plant_variant"])


def montecarlo_brick(data):
    return _mc_block(data["montecarlo_brick"], "The realistic brick, its effects drawn around their values")


def brick_run(data):
    from hostsim.studies.report import brick_summary
    return brick_summary(_scenario(data, "brick_realistic"))


def margins(data):
    from hostsim.studies.margins import margin_table
    meta = data["margins"]["_meta"]
    return ("Each effect alone on the ideal brick, the largest value with which the robot still balances %g s "
            "(%s bisection; where an effect has a sign, the smaller margin first, both in brackets).\n\n%s"
            % (meta["duration_s"], "make sim's coarse" if meta["coarse"] else "a", margin_table(data["margins"], markdown=True)))


def ablation(data):
    from hostsim.studies.margins import ablation_table, costliest
    res = data["margins"]
    labels = sorted({r["gains"] for r in res["ablation"]})
    return ("The realistic brick as shipped, then with the overrun stop lifted: all effects on, all but one (the one "
            "whose removal helps most first), all off, each alone; %d seed(s) a row.\n\n%s\n\nEach effect alone, "
            "costliest first: %s." % (res["_meta"]["seeds"], ablation_table(res, markdown=True), "; ".join(
                "%s gains: %s" % (l, ", ".join(costliest(res, l))) for l in labels)))


def load(data):
    from hostsim.studies.report import load_table
    return load_table(data["load"])


def driving(data):
    from hostsim.studies.report import drive_table
    return drive_table(data["drive"])


BLOCKS = {
    "results-summary": ("docs/results.md", summary),
    "results-firmware-section8": ("docs/results.md", firmware_section8),
    "results-roa": ("docs/results.md", roa),
    "results-montecarlo": ("docs/results.md", montecarlo),
    "brick-run": ("docs/realistic-brick.md", brick_run),
    "brick-montecarlo": ("docs/realistic-brick.md", montecarlo_brick),
    "brick-ablation": ("docs/realistic-brick.md", ablation),
    "brick-margins": ("docs/realistic-brick.md", margins),
    "brick-load": ("docs/realistic-brick.md", load),
    "brick-driving": ("docs/realistic-brick.md", driving),
}
