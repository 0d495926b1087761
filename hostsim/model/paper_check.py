"""Compare the ``paper`` variant with the paper's Appendix C; contrast the ``physical`` one.

``python -m hostsim paper-check`` prints, for |A|, |B| and |K|, the median and maximum
relative error over the entries whose printed magnitude exceeds 1e-3 (the printed matrices
lost their minus signs), how the physical model's A and B differ from the paper's, and the
spectral radius of A - B K for each of the two gains on each of the two models. Exits 1 if
the paper variant misses the 2 % tolerance.
"""
import argparse
import json
import os

import hostsim
import numpy as np

from hostsim.model.gains import DEFAULT_TS_S, design_gains
from hostsim.model.equations import state_scale_to_si
from hostsim.model.params import DEFAULT_PARAMS_PATH, load_params

APPENDIX_C = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "paper_appendix_c.json")
TOLERANCE = 0.02
SIGNIFICANT = 1e-3


def load_appendix_c(path=APPENDIX_C):
    with open(path) as f:
        doc = json.load(f)
    return {k[:-4]: np.array(doc[k]) for k in ("A_abs", "B_abs", "K_abs")}


def relative_errors(ours, printed, floor=SIGNIFICANT):
    """Relative error of |ours| against the printed magnitudes, over |printed| > floor."""
    mask = np.abs(printed) > floor
    return np.abs(np.abs(ours[mask]) - printed[mask]) / np.abs(printed[mask])


def to_si(g):
    """(A, B, K) of a design expressed with the state in SI units."""
    t = state_scale_to_si(g.variant)
    ti = np.linalg.inv(t)
    return t @ g.A @ ti, t @ g.B, g.K @ ti


def cross_spectral_radii(designs):
    """{(gain variant, model variant): max |eig(A - B K)|}, all in SI units."""
    si = {name: to_si(g) for name, g in designs.items()}
    out = {}
    for gname, (_, _, k) in si.items():
        for mname, (a, b, _) in si.items():
            out[(gname, mname)] = float(np.max(np.abs(np.linalg.eigvals(a - b @ k))))
    return out


def run(params=None, ts_s=0.005):
    """Compute every figure of the check; returns a dict (used by the tests too)."""
    params = load_params() if params is None else params
    designs = {name: design_gains(name, params, ts_s) for name in ("paper", "physical")}
    printed = load_appendix_c()
    paper = designs["paper"]
    errors = {}
    for key in ("A", "B", "K"):
        r = relative_errors(getattr(paper, key), printed[key])
        errors[key] = (float(np.median(r)), float(np.max(r)), int(r.size))
    sign_mismatch = {}
    # The physical model, in the paper's units (cm), against the paper's matrices.
    t_phys = state_scale_to_si(designs["physical"].variant)
    t_paper_inv = np.linalg.inv(state_scale_to_si(paper.variant))
    conv = t_paper_inv @ t_phys
    a_phys = conv @ designs["physical"].A @ np.linalg.inv(conv)
    b_phys = conv @ designs["physical"].B
    for key, ours, theirs in (("A", a_phys, paper.A), ("B", b_phys, paper.B)):
        mask = np.abs(theirs) > SIGNIFICANT
        rel = np.abs(ours[mask] - theirs[mask]) / np.abs(theirs[mask])
        flips = int(np.sum(np.sign(ours[mask]) != np.sign(theirs[mask])))
        sign_mismatch[key] = (float(np.median(rel)), float(np.max(rel)), flips, int(mask.sum()))
    return dict(errors=errors, physical_vs_paper=sign_mismatch,
                cross=cross_spectral_radii(designs), designs=designs)


def report(res):
    lines = ["Paper variant against Appendix C (entries with |printed| > %g):" % SIGNIFICANT,
             "  matrix  entries  median rel. err  max rel. err  (limit %.0f %%)" % (TOLERANCE * 100)]
    for key, (med, mx, count) in res["errors"].items():
        lines.append("  |%s|     %5d     %10.4f %%   %9.4f %%  %s" % (
            key, count, med * 100, mx * 100, "ok" if mx <= TOLERANCE else "FAIL"))
    lines.append("")
    lines.append("Physical variant against the paper variant (same units, cm):")
    lines.append("  matrix  median rel. diff  max rel. diff  sign flips")
    for key, (med, mx, flips, count) in res["physical_vs_paper"].items():
        lines.append("  %s       %10.1f %%   %10.1f %%   %d of %d" % (key, med * 100, mx * 100, flips, count))
    lines.append("")
    lines.append("Spectral radius of A - B K (rows: gains, columns: model):")
    lines.append("  gains \\ model      paper    physical")
    for g in ("paper", "physical"):
        lines.append("  %-16s %8.5f   %8.5f" % (g, res["cross"][(g, "paper")], res["cross"][(g, "physical")]))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("paper-check"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", default=DEFAULT_PARAMS_PATH, help="robot parameters JSON (default params/robot.json)")
    ap.add_argument("--ts", type=float, default=DEFAULT_TS_S, help="loop period in seconds (default 0.005)")
    args = ap.parse_args(argv)
    res = run(load_params(args.params), args.ts)
    print(report(res))
    ok = all(mx <= TOLERANCE for _, mx, _ in res["errors"].values())
    return 0 if ok else 1

