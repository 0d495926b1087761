"""Gain generation: model -> linearization -> discretization -> LQR + detector -> JSON.

``python -m hostsim gains [--variant paper|physical|all] [--ts 0.005] [--params FILE]
[--out-dir gains] [--check]`` writes ``gains/<variant>.json`` (schema in
docs/architecture.md). Another period or another parameters file goes to a file of its own,
named by what differs (``physical-ts0.010.json``, ``physical-identified.json``): the
deployable ``gains/<variant>.json`` is only ever the design of ``params/robot.json`` at 5 ms.

The committed files are the source of truth. A regeneration that agrees with the file on
disk within the tolerances of ``compare_documents`` leaves the file untouched (BLAS kernels
differ between CPUs in the last bits, and the Riccati solution amplifies that to about 1e-9
of |K|); only a real change rewrites it. Output is deterministic otherwise: no wall-clock
time, floats rounded to 12 significant digits. ``--check`` compares instead of writing and
exits 1 on a difference.
"""
import argparse
import dataclasses
import json
import os
import re
import sys

from typing import Optional

import numpy as np

from hostsim.errors import TipbotError
from hostsim.model import design
from hostsim.model.equations import INPUT_NAMES, STATE_NAMES, RobotModel, Variant, get_variant, state_scale_to_si
from hostsim.model.params import DEFAULT_PARAMS_PATH, load_params, params_hash
from hostsim.paths import GAINS_DIR
from tipbot_fw.gains import ACTUATED_INPUTS

SCHEMA_VERSION = 1
DEFAULT_TS_S = 0.005
DEFAULT_OUT_DIR = GAINS_DIR
VARIANT_NAMES = ("paper", "physical")

# How far a regenerated number may move from the committed one, relative to the norm of its
# whole matrix or list (an entry near zero is rounding noise of the large ones beside it).
# The model (expm of the linearization), the weights and the detector (pole placement) come
# from backward-stable computations: BLAS kernels move them by ~1e-15 of their norm, and
# the 12-digit rounding of the file by up to 5e-13. K and K_w solve the Riccati equation,
# which the paper's Q (1e7 on th1 beside 1 on the rates) makes ill-conditioned: Haswell,
# SkylakeX, Zen and Prescott kernels move them by up to 1.1e-9 of their norm (paper
# variant). Both tolerances leave a factor of about 1000 above what was measured.
RTOL_WELL_CONDITIONED = 1e-9
RTOL_RICCATI = 1e-6
NUMERIC_FIELDS = {
    "A": RTOL_WELL_CONDITIONED, "B": RTOL_WELL_CONDITIONED, "C": RTOL_WELL_CONDITIONED,
    "E": RTOL_WELL_CONDITIONED, "Q": RTOL_WELL_CONDITIONED, "R": RTOL_WELL_CONDITIONED,
    "L1": RTOL_WELL_CONDITIONED, "L2": RTOL_WELL_CONDITIONED, "G_w": RTOL_WELL_CONDITIONED,
    "detector_eigenvalues": RTOL_WELL_CONDITIONED, "open_loop_eigenvalues_abs": RTOL_WELL_CONDITIONED,
    "K": RTOL_RICCATI, "K_w": RTOL_RICCATI,
    # eigenvalues of A - B K: K's effect, well-conditioned in K (measured: 2e-11)
    "closed_loop_spectral_radius": RTOL_WELL_CONDITIONED,
    "robust_to_models.worst_spectral_radius": RTOL_WELL_CONDITIONED,
}
# The physical gains must also stabilize the paper's model: the two bracket what is least
# certain about the drivetrain (rotor inertia Jm from 0 to Table 2's value, the wheel
# motors' reaction on link 1 absent or present).
ROBUST_AGAINST = ("paper",)


@dataclasses.dataclass(frozen=True)
class GainDesign:
    """Everything designed for one model variant (arrays in the variant's units, d in cm for
    ``paper``); to_document() makes the gains file of it."""
    variant: Variant
    model: RobotModel
    ts_s: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    E: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    r_wheel_scale: float             # the wheel inputs' weight multiplier (physical variant)
    robust_to_models: Optional[bool]  # whether K also stabilizes ROBUST_AGAINST (None: not checked)
    robust_worst_radius: Optional[float]
    K: np.ndarray
    P: np.ndarray                    # the Riccati solution
    K_w: np.ndarray
    L1: np.ndarray
    L2: np.ndarray
    G_w: np.ndarray
    closed_loop_eigenvalues: np.ndarray
    detector_eigenvalues: np.ndarray
    structure: dict                  # design.structure_report


def design_gains(variant, params, ts_s=DEFAULT_TS_S, detector_poles=None):
    """Design everything the firmware needs for one model variant -> GainDesign."""
    if isinstance(variant, str):
        variant = get_variant(variant)
    model = RobotModel(variant, params)
    ac, bc = model.linearize()
    a, b = design.discretize(ac, bc, ts_s)
    n = a.shape[0]
    c = np.eye(n)
    e_mat = b.copy()
    cm_per_unit = variant.d_scale_m * 100.0
    q, r = design.weights_in_units(design.PAPER_Q_DIAG_CM, design.PAPER_R_DIAG,
                                   [cm_per_unit] * 2 + [1] * 3 + [cm_per_unit] * 2 + [1] * 3)
    r_wheel_scale, robust, worst = 1.0, None, None
    if variant.paper_conventions:
        k, p, cl_eig = design.dlqr(a, b, q, r, ACTUATED_INPUTS)
    else:
        check_models = [design.discrete_model_si(RobotModel(name, params), ts_s) for name in ROBUST_AGAINST]
        r_wheel_scale, r, k, p, cl_eig, robust, worst = design.robust_wheel_weight(
            a, b, q, r, ACTUATED_INPUTS, check_models, state_scale_to_si(variant))
    k_w = design.disturbance_gain(a, b, q, r, k, p, e_mat)
    l1, l2, g_w, det_eig = design.robust_detector(a, b, c, e_mat, ACTUATED_INPUTS, detector_poles)
    return GainDesign(variant=variant, model=model, ts_s=float(ts_s), A=a, B=b, C=c, E=e_mat, Q=q, R=r,
                r_wheel_scale=r_wheel_scale, robust_to_models=robust, robust_worst_radius=worst,
                K=k, P=p, K_w=k_w, L1=l1, L2=l2, G_w=g_w,
                closed_loop_eigenvalues=cl_eig, detector_eigenvalues=det_eig,
                structure=design.structure_report(a, b, c, ACTUATED_INPUTS))


def _num(x):
    # 12 significant digits hide last-bit differences between LAPACK builds; + 0.0 folds -0.0.
    return float("%.12g" % x) + 0.0


def _matrix(m):
    return [[_num(v) for v in row] for row in np.asarray(m, dtype=float)]


def _generator():
    import control
    import scipy
    import sympy
    return "hostsim.gains (numpy %s, scipy %s, sympy %s, control %s)" % (
        np.__version__, scipy.__version__, sympy.__version__, control.__version__)


def to_document(g):
    """The JSON document of a design (plain Python types, rounded floats)."""
    variant, params = g.variant, g.model.params
    st = g.structure
    doc = {
        "schema_version": SCHEMA_VERSION,
        "model_variant": variant.name,
        "model_options": variant.options(),
        "ts_s": _num(g.ts_s),
        "state_names": list(STATE_NAMES),
        "state_units": list(variant.state_units),
        "input_names": list(INPUT_NAMES),
        "input_units": ["V"] * len(INPUT_NAMES),
        "actuated_inputs": list(ACTUATED_INPUTS),
        "u_max_v": _num(params["u_max_v"]),
        "r_wheel_scale": _num(g.r_wheel_scale),
        "robust_to_models": None if g.robust_to_models is None else {
            "models": list(ROBUST_AGAINST), "stabilized": g.robust_to_models,
            "worst_spectral_radius": _num(g.robust_worst_radius)},
        "closed_loop_spectral_radius": _num(np.max(np.abs(g.closed_loop_eigenvalues))),
        "detector_eigenvalues": [_num(z.real) for z in sorted(g.detector_eigenvalues, key=lambda z: z.real)],
        "controllability_rank": st["controllability_rank"],
        "observability_rank": st["observability_rank"],
        "open_loop_eigenvalues_abs": [_num(abs(z)) for z in st["open_loop_eigenvalues"]],
        "parameters": {k: _num(v) for k, v in sorted(params.items())},
        "parameters_sha256": params_hash(params),
        "generator": _generator(),
    }
    for key in ("A", "B", "C", "E", "K", "K_w", "L1", "L2", "G_w", "Q", "R"):
        doc[key] = _matrix(getattr(g, key))
    return doc


def dumps(doc):
    """JSON text with one matrix row per line (readable diffs), keys in a fixed order."""
    lines = []
    for key in sorted(doc, key=lambda k: (isinstance(doc[k], list) and doc[k] and isinstance(doc[k][0], list), k)):
        value = doc[key]
        if isinstance(value, list) and value and isinstance(value[0], list):
            rows = ",\n".join("    " + json.dumps(row) for row in value)
            lines.append('  %s: [\n%s\n  ]' % (json.dumps(key), rows))
        else:
            lines.append("  %s: %s" % (json.dumps(key), json.dumps(value, sort_keys=True)))
    return "{\n" + ",\n".join(lines) + "\n}\n"


def summary(g):
    st = g.structure
    ol = ", ".join("%.4g" % abs(z) for z in st["open_loop_eigenvalues"])
    return "\n".join([
        "variant %s: ts %.4g s, state units %s" % (g.variant.name, g.ts_s, "/".join(sorted(set(g.variant.state_units)))),
        "  controllability rank %d, observability rank %d (of 10)" % (st["controllability_rank"], st["observability_rank"]),
        "  open-loop |eig|: %s" % ol,
        "  closed-loop spectral radius of A - B K: %.6f" % np.max(np.abs(g.closed_loop_eigenvalues)),
        "  detector eigenvalues (Abar - L1 C): %s" % ", ".join("%.4g" % z.real for z in g.detector_eigenvalues),
    ] + robustness_lines(g))


def robustness_lines(g):
    if g.robust_to_models is None:
        return []
    if g.robust_to_models:
        return ["  wheel input weight x%g: the gain also stabilizes the %s model(s) (worst radius %.5f)"
                % (g.r_wheel_scale, "/".join(ROBUST_AGAINST), g.robust_worst_radius)]
    return ["  WARNING: no wheel input weight makes this gain stabilize the %s model(s) at ts %.4g s "
            "(worst radius %.4f); using the paper's weights" % ("/".join(ROBUST_AGAINST), g.ts_s, g.robust_worst_radius)]


def output_name(variant, ts_s=DEFAULT_TS_S, params_path=DEFAULT_PARAMS_PATH):
    """File name of a design: ``<variant>.json`` for params/robot.json at the default period,
    else named by what differs (``physical-ts0.010.json``, ``physical-identified.json``)."""
    parts = [variant]
    if float(ts_s) != DEFAULT_TS_S:
        text = "%.3f" % ts_s
        if float(text) != float(ts_s):
            text = "%.6g" % ts_s
        parts.append("ts" + text)
    if os.path.realpath(params_path) != os.path.realpath(DEFAULT_PARAMS_PATH):
        stem = os.path.splitext(os.path.basename(params_path))[0]
        parts.append(re.sub(r"[^A-Za-z0-9_.]+", "_", stem) or "params")
    return "-".join(parts) + ".json"


def _leaves(doc, prefix=""):
    """{dotted key: value} of a document, descending into objects (lists are values)."""
    out = {}
    for key, value in doc.items():
        if isinstance(value, dict) and value:
            out.update(_leaves(value, prefix + key + "."))
        else:
            out[prefix + key] = value
    return out


def _relative_difference(old, new):
    """max |old - new| over max |old| (numbers or nested lists); None if the shapes differ."""
    try:
        a, b = np.asarray(old, dtype=float), np.asarray(new, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.shape != b.shape:
        return None
    if a.size == 0:
        return 0.0
    scale = float(np.max(np.abs(a))) or 1.0
    return float(np.max(np.abs(a - b))) / scale


# K judged by its effect: the committed K on the regenerated model must give the regenerated
# closed loop's spectral radius. 1e-7 moves the slowest mode's time constant (0.8 s at
# radius 0.9937) by 2e-5 of itself; the kernels differ by 2e-11.
EFFECT_ATOL_RADIUS = 1e-7


def _k_effect(committed, fresh):
    """|rho(A - B K_committed) - rho(A - B K_fresh)| on the regenerated A, B; None if not computable."""
    try:
        a, b = np.asarray(fresh["A"], dtype=float), np.asarray(fresh["B"], dtype=float)
        k_old, k_new = np.asarray(committed["K"], dtype=float), np.asarray(fresh["K"], dtype=float)
        radius = lambda k: float(np.max(np.abs(np.linalg.eigvals(a - b @ k))))  # noqa: E731
        return abs(radius(k_old) - radius(k_new))
    except (KeyError, TypeError, ValueError, np.linalg.LinAlgError):
        return None


def compare_documents(committed, fresh):
    """Compare a committed gains document with a regenerated one.

    -> (differences, agreement): one line per field that changed beyond its tolerance
    (numbers: NUMERIC_FIELDS, relative to the field's norm; K also by its effect on the
    closed loop; everything else, the provenance included, exactly), and
    {numeric field: relative difference} of those that agree.
    """
    old, new = _leaves(committed), _leaves(fresh)
    differences, agreement = [], {}
    for key in sorted(set(old) | set(new)):
        if key not in old or key not in new:
            differences.append("%s: %s" % (key, "not in the file" if key not in old else "no longer generated"))
        elif key in NUMERIC_FIELDS:
            rel = _relative_difference(old[key], new[key])
            if rel is None:
                differences.append("%s: shape changed" % key)
            elif rel > NUMERIC_FIELDS[key]:
                differences.append("%s: differs by %.2g of its norm (tolerance %g)" % (key, rel, NUMERIC_FIELDS[key]))
            else:
                agreement[key] = rel
        elif old[key] != new[key]:
            differences.append("%s: %s -> %s" % (key, _short(old[key]), _short(new[key])))
    effect = _k_effect(committed, fresh)
    if effect is not None and effect > EFFECT_ATOL_RADIUS:
        differences.append("K: on the regenerated model the file's K gives a closed-loop spectral radius %.2g "
                           "away from the regenerated K's (tolerance %g)" % (effect, EFFECT_ATOL_RADIUS))
    return differences, agreement


def _short(value, width=60):
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= width else text[:width - 3] + "..."


def compare_with_file(path, doc):
    """-> (differences, agreement) of ``doc`` against the gains file at ``path`` (see
    compare_documents); a missing or unreadable file is one difference."""
    try:
        with open(path) as f:
            committed = json.load(f)
    except FileNotFoundError:
        return ["%s does not exist" % path], {}
    except (OSError, ValueError) as exc:
        return ["%s is not readable JSON (%s)" % (path, exc)], {}
    if not isinstance(committed, dict):
        return ["%s is not a gains document" % path], {}
    return compare_documents(committed, doc)


def _shown(path):
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


def agreement_text(agreement):
    """The field nearest its tolerance, e.g. 'nearest its tolerance: K, by 3.5e-10 of its norm (1e-06)'."""
    if not any(agreement.values()):
        return "identical to the last digit"
    key = max(agreement, key=lambda k: agreement[k] / NUMERIC_FIELDS[k])
    return "nearest its tolerance: %s, by %.2g of its norm (%g)" % (key, agreement[key], NUMERIC_FIELDS[key])


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m hostsim gains", description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", choices=VARIANT_NAMES + ("all",), default="all",
                    help="model variant to design (default all)")
    ap.add_argument("--ts", type=float, default=DEFAULT_TS_S,
                    help="loop period in seconds (default 0.005; another goes to <variant>-ts<TS>.json)")
    ap.add_argument("--params", default=DEFAULT_PARAMS_PATH,
                    help="robot parameters JSON (default params/robot.json; another goes to <variant>-<name>.json)")
    ap.add_argument("--out-dir", default=DEFAULT_OUT_DIR, help="where the gains files are (default gains/)")
    ap.add_argument("--check", action="store_true", help="compare with the files instead of writing them")
    args = ap.parse_args(argv)
    names = VARIANT_NAMES if args.variant == "all" else (args.variant,)
    try:
        params = load_params(args.params)
        status = 0
        for name in names:
            g = design_gains(name, params, args.ts)
            print(summary(g))
            doc = to_document(g)
            path = os.path.join(args.out_dir, output_name(name, args.ts, args.params))
            shown = _shown(path)
            differences, agreement = compare_with_file(path, doc)
            if not differences:
                print("  %s is up to date: the regenerated numbers agree with it (%s); left untouched"
                      % (shown, agreement_text(agreement)))
                continue
            new = not os.path.exists(path)
            if args.check:
                print("  %s %s (run make gains)%s" % (shown, "does not exist" if new else "differs from a fresh generation",
                                                      "" if new else ":"))
                status = 1
            else:
                os.makedirs(args.out_dir, exist_ok=True)
                with open(path, "w") as f:
                    f.write(dumps(doc))
                print("  wrote %s%s" % (shown, " (new file)" if new else ", which changed:"))
            if not new:
                for line in differences[:12]:
                    print("    " + line)
                if len(differences) > 12:
                    print("    ... and %d more" % (len(differences) - 12))
        return status
    except TipbotError as exc:
        print("error: %s" % exc, file=sys.stderr)
        return 2

