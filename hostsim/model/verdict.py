"""What ``make gains PARAMS=...`` tells the owner of a robot of their own: the predicted margins of
their robot, how well its parameters are known, and a plain verdict (deploy, or measure again and
which measurement).

The verdict: **deploy** when the design holds its whole uncertainty set (hostsim.model.kalman,
with the parameters' spread: hostsim.model.spread, which covers what the experiments leave loose:
the links' own inertias) and the parameters come from the fall and both joint swings
(hostsim.model.robotfit; the axle swing, which gives a1, is not required); else **measure
again**, naming the experiments not done, or the one that measures the part of the robot the
design does not hold (hostsim.model.spread.MEASUREMENT_OF).
"""
from hostsim.model import bodies, preflight
from hostsim.model.spread import MEASUREMENT_OF

# What each experiment's fit is called in the file's uncertainty.measurements, by link
MEASURED = {"1": "fall_ratio", "2": "lever2", "3": "lever3"}
KEY_PARAMETERS = ("m1_kg", "m2_kg", "m3_kg", "l1_m", "l2_m", "l3_m", "j1_kg_m2", "j2_kg_m2", "j3_kg_m2")


def report(g, spread):
    """-> (lines, verdict text) for a design g (hostsim.model.gains.GainDesign)."""
    p = g.model.params
    lines = ["your robot (%s variant):" % g.variant.name,
             "  fall pole %.3f 1/s, levers a1 %.4g, a2 %.4g, a3 %.4g kg m (hostsim.model.bodies)" % (
                 (bodies.fall_pole(p),) + bodies.levers(p))]
    lines += ["  predicted margins: worst spectral radius %.5f (at most %.4f), least damping %.3f (at least %.2f)"
              % (g.margins.radius, 0.9995, g.margins.damping, 0.05)]
    lines += ["  how far off the robot may be for these gains (the pre-flight check's intervals):"]
    lines += ["  " + x for x in preflight.describe(g.preflight)]
    loose = []
    if spread is None:
        lines.append("  confidence: the parameters file says nothing of its uncertainty (no uncertainty block)")
    else:
        sig = ", ".join("%s %.0f %%" % (n, 100 * spread.rel_sigma(n)) for n in KEY_PARAMETERS if n in spread.names)
        lines.append("  confidence (one standard deviation, relative): %s" % (sig or "-"))
        for name, m in sorted(spread.measurements.items()):
            lines.append("    %s: %s" % (name, m.get("summary", m) if isinstance(m, dict) else m))
        loose = [k for k, name in sorted(MEASURED.items()) if name not in spread.measurements]
    if not g.margins.robust:
        where = g.margins.radius_at if g.margins.radius > 0.9995 else g.margins.damping_at
        link = spread.loosest_link(where[3] if isinstance(where[3], str) else None) if spread is not None else None
        what = MEASUREMENT_OF.get(link, "the fall and swing tests (docs/your-robot.md)")
        verdict = ("MEASURE AGAIN: these gains do not hold every robot the parameters allow (%s); measure %s, "
                   "then make gains again" % (", ".join(str(w) for w in where), what))
    elif spread is None or loose:
        verdict = "MEASURE: the parameters are %s; run %s, then python -m hostsim fit-robot" % (
            "not fitted to experiments" if spread is None or len(loose) == 3 else "missing an experiment",
            " and ".join(MEASUREMENT_OF[k] for k in (loose or sorted(MEASURED))))
    else:
        verdict = ("DEPLOY: the gains hold every robot within the fit's spread; run the pre-flight check on the "
                   "brick first (python3 -m tipbot_fw check --gains gains.json --fall-log LOG)")
    return lines, verdict
