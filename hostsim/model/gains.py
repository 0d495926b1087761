"""Gain generation: model -> linearization -> discretization -> LQR, Kalman filter, detector -> JSON.

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
import itertools
import json
import os
import re
import sys

from typing import Optional

import hostsim
import numpy as np

from hostsim.errors import TipbotError
from hostsim.model import design
from hostsim.model import kalman
from hostsim.model import preflight
from hostsim.model import reference
from hostsim.model import verdict
from hostsim.model.spread import load_spread
from hostsim.model.equations import INPUT_NAMES, STATE_NAMES, RobotModel, Variant, get_variant, state_scale_to_si
from hostsim.model.params import DEFAULT_PARAMS_PATH, load_params, params_hash
from hostsim.paths import GAINS_DIR
from tipbot_fw.cores.kalman_design import fold, spectral_radius
from tipbot_fw.gains import gains_from_dict
from tipbot_fw.vocabulary import ACTUATED_INPUTS, GAINS_SCHEMA_VERSION, integrator_count

DEFAULT_TS_S = 0.005
DEFAULT_OUT_DIR = GAINS_DIR
VARIANT_NAMES = ("paper", "physical")

# How far a regenerated number may move from the committed one, relative to the norm of its
# whole matrix or list (an entry near zero is rounding noise of the large ones beside it).
# The model (expm of the linearization), the weights, the noise settings and the detector (pole
# placement) come from backward-stable computations: BLAS kernels move them by ~1e-15 of their
# norm, and the 12-digit rounding of the file by up to 5e-13. K and K_w solve the control
# Riccati equation, which the paper's Q (1e7 on th1 beside 1 on the rates) makes
# ill-conditioned: Haswell, SkylakeX, Zen and Prescott kernels move them by up to 1.1e-9 of
# their norm (paper variant); the Kalman block's K and its folded law carry them (5e-10). The
# filter's own Riccati equation is well-conditioned: its gain L and posterior moved by 2e-12.
# Spectral radii are eigenvalues, well-conditioned (2e-11); the least damping ratio of the
# robust loop is that of a slow mode (|z| ~ 0.999), whose ln|z| amplifies the eigenvalue's
# change about a thousandfold (1.4e-9 measured). Both tolerances leave a factor of about 500 to
# 1000 above what was measured.
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
    "state_feedback_spectral_radius.paper": RTOL_WELL_CONDITIONED,
    "state_feedback_spectral_radius.physical": RTOL_WELL_CONDITIONED,
    "robust_to_models.worst_spectral_radius": RTOL_WELL_CONDITIONED,
    "robust_to_models.least_damping": RTOL_RICCATI,
    # the Kalman block (schema 2)
    "kalman.A": RTOL_WELL_CONDITIONED, "kalman.B": RTOL_WELL_CONDITIONED, "kalman.C": RTOL_WELL_CONDITIONED,
    "kalman.Q": RTOL_WELL_CONDITIONED, "kalman.R": RTOL_WELL_CONDITIONED,
    "kalman.L": RTOL_WELL_CONDITIONED, "kalman.posterior_std": RTOL_WELL_CONDITIONED,
    "kalman.filter_eigenvalues_abs": RTOL_WELL_CONDITIONED,
    "kalman.K": RTOL_RICCATI, "kalman.law.M": RTOL_RICCATI,
    # the integrators' limit: a share of u_max over K_z's rows
    "kalman.integral.limit_m_s": RTOL_RICCATI,
    # the drive reference: K's velocity columns times the motion, and the model's inputs for it
    "kalman.reference.G": RTOL_RICCATI, "kalman.reference.U": RTOL_WELL_CONDITIONED,
    "kalman.reference.lean_rad": RTOL_WELL_CONDITIONED,
    # the pre-flight block: the model's figures, and intervals found by bisection to 0.3 % and
    # rounded to 3 digits (a kernel's last bits could only move a bound by one rounding step)
    "preflight.fall_pole_1_s": RTOL_WELL_CONDITIONED, "preflight.levers_kg_m": RTOL_WELL_CONDITIONED,
    "preflight.wheel_term_kg_m2": RTOL_WELL_CONDITIONED, "preflight.lever_axle_kg_m": RTOL_WELL_CONDITIONED,
    **{"preflight.intervals." + name: 0.01 for name in ("fall_pole_1_s", "lever2_kg_m", "lever3_kg_m")},
    **{"preflight.families.%s.factors" % name: 0.01 for name in ("fall_pole_1_s", "lever2_kg_m", "lever3_kg_m")},
    **{"kalman.reference.limits." + name: RTOL_WELL_CONDITIONED for name in (
        "speed_mps", "accel_mps2", "jerk_mps3", "yaw_rate_dps", "yaw_accel_dps2", "yaw_jerk_dps3")},
}
# Both designs must hold both model variants (kalman.UncertaintySet): the two bracket what is
# least certain about the drivetrain (rotor inertia Jm from 0 to Table 2's value, the wheel
# motors' reaction on link 1 absent or present).


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
    joint_weight_scale: float        # the joint angles' weight multiplier (physical variant)
    margins: kalman.Margins          # of the loop over kalman.UncertaintySet (robust or not)
    K: np.ndarray
    P: np.ndarray                    # the Riccati solution
    K_w: np.ndarray
    L1: np.ndarray
    L2: np.ndarray
    G_w: np.ndarray
    closed_loop_eigenvalues: np.ndarray
    detector_eigenvalues: np.ndarray
    structure: dict                  # design.structure_report
    kalman: kalman.KalmanDesign      # the firmware's default estimator (SI)
    state_feedback_radii: dict       # spectral radius of A - B K on each model (the detector's concern)
    spread: Optional[object] = None  # hostsim.model.spread.Spread the design also holds, or None
    preflight: Optional[dict] = None  # the gains file's preflight block (hostsim.model.preflight)


def design_gains(variant, params, ts_s=DEFAULT_TS_S, detector_poles=None, noise=None, spread=None):
    """Design everything the firmware needs for one model variant -> GainDesign (noise: the
    Kalman filter's hostsim.model.kalman.NoiseSettings, default its defaults; spread: the
    parameters' hostsim.model.spread.Spread, whose robots the design must hold too)."""
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
    chosen = robust_design(variant, params, ts_s, a, b, q, r, e_mat, noise, spread)
    l1, l2, g_w, det_eig = design.robust_detector(a, b, c, e_mat, ACTUATED_INPUTS, detector_poles)
    return GainDesign(variant=variant, model=model, ts_s=float(ts_s), A=a, B=b, C=c, E=e_mat, Q=chosen.Q, R=chosen.R,
                      r_wheel_scale=chosen.r_wheel_scale, joint_weight_scale=chosen.joint_weight_scale,
                      margins=chosen.margins,
                      K=chosen.K, P=chosen.P, K_w=chosen.K_w, L1=l1, L2=l2, G_w=g_w,
                      closed_loop_eigenvalues=chosen.eig, detector_eigenvalues=det_eig,
                      structure=design.structure_report(a, b, c, ACTUATED_INPUTS), kalman=chosen.kalman,
                      state_feedback_radii=state_feedback_radii(variant, params, ts_s, chosen.K),
                      spread=spread, preflight=preflight.preflight_block(chosen.kalman, params, ts_s))


@dataclasses.dataclass(frozen=True)
class RobustLaw:
    """What robust_design chose: the joint angles' and the wheel inputs' weight factors and the
    weights Q, R they gave, the LQR (K, its Riccati solution P, the closed loop's eigenvalues), K_w, the Kalman filter and law
    (hostsim.model.kalman.KalmanDesign) and their margins on the uncertainty set (None until
    margins are known)."""
    r_wheel_scale: float
    joint_weight_scale: float
    Q: np.ndarray
    R: np.ndarray
    K: np.ndarray
    P: np.ndarray
    eig: np.ndarray
    K_w: np.ndarray
    kalman: "kalman.KalmanDesign"
    margins: Optional["kalman.Margins"] = None


def robust_design(variant, params, ts_s, a, b, q, r, e_mat, noise=None, spread=None):
    """The LQR and the Kalman filter, made robust together: the first joint weight of
    design.JOINT_WEIGHT_LADDER, wheel input weight of design.WHEEL_WEIGHT_LADDER (both the
    physical variant's; the paper's weights for the paper variant) and input-noise scale of
    kalman.INPUT_NOISE_LADDER whose loop (plant, filter, law) has its modes all decay and
    oscillate with enough damping on every plant of kalman.UncertaintySet (kalman.Margins.robust;
    for our designs a payload on link 3 too), the physical variant's law with integral action
    first (law_design: the filter then estimates joint 2's input disturbance too,
    kalman.INTEGRAL_DISTURBANCE_INPUTS), without it if no step holds with it. When none does,
    the plain design (all factors 1, the integrators if the variant has them). -> RobustLaw."""
    ours = not variant.paper_conventions        # the paper's law is the paper's: no payload asked of it
    uncertainty = kalman.UncertaintySet(params, ts_s, () if spread is None else spread.robots(params), payload=ours)
    t = state_scale_to_si(variant)
    ti = np.linalg.inv(t)
    base = kalman.NoiseSettings() if noise is None else noise
    ladder = design.WHEEL_WEIGHT_LADDER if ours else (1.0,)
    joints = design.JOINT_WEIGHT_LADDER if ours else (1.0,)
    # our designs: with integral action if any step of the ladders holds, else without
    integral_options = (True, False) if ours else (False,)
    plain = None
    for integral, joint, factor in itertools.product(integral_options, joints, ladder):
        q_try = np.array(q, dtype=float)
        for j in design.JOINT_STATES:
            q_try[j, j] *= joint
        r_try = np.array(r, dtype=float)
        for j in (0, 1):
            r_try[j, j] *= factor
        k, p, eig, k_w, k_z = law_design(a, b, q_try, r_try, e_mat, ts_s, integral)
        dist = kalman.INTEGRAL_DISTURBANCE_INPUTS if integral else base.disturbance_inputs
        for scale in kalman.INPUT_NOISE_LADDER:
            ns = dataclasses.replace(base, input_noise_scale=scale, disturbance_inputs=dist)
            kd = kalman.design_kalman(t @ a @ ti, t @ b, k @ ti, k_w, params["rw_m"], ts_s, ns,
                                      integral=None if k_z is None else kalman.integral_law(
                                          k_z / t[0, 0], params["u_max_v"]))
            found = RobustLaw(r_wheel_scale=factor, joint_weight_scale=joint, Q=q_try, R=r_try, K=k, P=p, eig=eig,
                              K_w=k_w, kalman=kd)
            if plain is None:
                plain = found
            if uncertainty.holds(kd):
                return dataclasses.replace(found, margins=uncertainty.margins(kd))
    return dataclasses.replace(plain, margins=uncertainty.margins(plain.kalman))


# Integral action on the wheel positions (tipbot_fw.cores.kalman, "Integral action"), in the designs
# that are ours (the paper's variant keeps the paper's law): the integral's weight is the wheel
# position's, spread over INTEGRAL_TIME_S (Bryson: a position error of 1 cm held that long costs
# as much as 1 cm), so the integrators take out an offset in a few times that, slower than the
# balancing and faster than the filter's slowest mode (the gyro bias's, ~7 s).
INTEGRAL_TIME_S = 2.0
# The joints' motors among the model's five inputs (u_th2, u_th3).
JOINT_INPUTS = (3, 4)


def law_design(a, b, q, r, e_mat, ts_s, integral):
    """(K, P, closed-loop eigenvalues, K_w, K_z or None) in the variant's units: the LQR, with
    integral action on the wheel positions if `integral` (design.dlqi)."""
    if not integral:
        k, p, eig = design.dlqr(a, b, q, r, ACTUATED_INPUTS)
        return k, p, eig, design.disturbance_gain(a, b, q, r, k, p, e_mat), None
    rows = (0, 1)
    k, k_z, p, eig = design.dlqi(a, b, q, r, ACTUATED_INPUTS, ts_s, q[0, 0] / INTEGRAL_TIME_S ** 2, rows)
    az, bz = design.integrator_model(a, b, ts_s, rows)
    e_z = design.integrator_model(a, e_mat, ts_s, rows)[1]
    k_w = design.disturbance_gain(az, bz, None, r, np.hstack([k, k_z]), p, e_z)
    # a joint's estimated disturbance (kalman.INTEGRAL_DISTURBANCE_INPUTS) is the filter's, not
    # the law's: compensated, it would close an integrator around the joint's Coulomb friction
    # and backlash, which hunts (kalman.NoiseSettings)
    k_w[:, list(JOINT_INPUTS)] = 0.0
    return k, p, eig, k_w, k_z[list(ACTUATED_INPUTS)]


def state_feedback_radii(variant, params, ts_s, k):
    """Spectral radius of A - B K (perfect state feedback) on each model variant."""
    k_si = k @ np.linalg.inv(state_scale_to_si(variant))
    out = {}
    for name in VARIANT_NAMES:
        am, bm = design.discrete_model_si(RobotModel(name, params), ts_s)
        out[name] = spectral_radius(am - bm @ k_si)
    return out


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
        "schema_version": GAINS_SCHEMA_VERSION,
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
        "joint_weight_scale": _num(g.joint_weight_scale),
        "robust_to_models": dict(kalman.UncertaintySet.describe(not variant.paper_conventions), stabilized=g.margins.robust,
                                 **({} if g.spread is None else {"parameter_spread": g.spread.describe()}),
                                 worst_spectral_radius=_num(g.margins.radius),
                                 worst_radius_at=_rounded(list(g.margins.radius_at)),
                                 least_damping=_num(g.margins.damping),
                                 least_damping_at=_rounded(list(g.margins.damping_at)),
                                 input_noise_scale=_num(g.kalman.noise.input_noise_scale),
                                 what="the loop of plant + Kalman filter + law on each model variant, with the new "
                                      "duties landing each delay into the tick, the motors' gain scaled, the wheels "
                                      "of another radius; stabilized: every mode decays (radius <= radius_max) and "
                                      "every one above damping_above_hz has a damping ratio >= damping_min"),
        "state_feedback_spectral_radius": {k: _num(v) for k, v in sorted(g.state_feedback_radii.items())},
        # of A - B K (the file's law without the Kalman block's integrators, as the firmware checks)
        "closed_loop_spectral_radius": _num(spectral_radius(g.A - g.B @ g.K)),
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
    kal = g.kalman.document()
    reference_doc = drive_reference(g)
    if reference_doc is not None:
        kal["reference"] = reference_doc
    doc["kalman"] = _rounded(kal)
    if g.preflight is not None:
        doc["preflight"] = _rounded(g.preflight)
    return doc


def drive_reference(g):
    """The Kalman block's drive reference (hostsim.model.reference) on the design's own model, or
    None for a model that cannot follow one (its motion equations singular: no driving, the
    firmware says so)."""
    ac, bc = g.model.linearize()
    t = state_scale_to_si(g.variant)
    ac_si, bc_si = t @ ac @ np.linalg.inv(t), t @ bc
    params = g.model.params
    try:
        return reference.reference_block(ac_si, bc_si[:, list(ACTUATED_INPUTS)], g.kalman.K, params["u_max_v"],
                                         params["track_m"])
    except np.linalg.LinAlgError:
        return None


def with_law(doc, k_file=None, k_w=None, note=""):
    """A gains document with another law: K (file units, 5 x 10) and/or K_w (5 x 5); the Kalman
    block's K_a and folded law follow (the filter itself is unchanged). For baselines and
    diagnoses (the PD baseline, K_w = 0), not for the robot."""
    out = json.loads(json.dumps(doc))
    if k_file is not None:
        out["K"] = np.asarray(k_file, dtype=float).tolist()
    if k_w is not None:
        out["K_w"] = np.asarray(k_w, dtype=float).tolist()
    a, b, k = (np.array(out[key]) for key in ("A", "B", "K"))
    out["closed_loop_spectral_radius"] = spectral_radius(a - b @ k)
    si = gains_from_dict(dict(out, kalman=doc["kalman"]), "<with_law>", check_kalman=False)
    kal = out["kalman"]
    dist = [i for i, name in enumerate(("w_r", "w_l", "w_th2", "w_th3")) if name in kal["state_names"]]
    nz = integrator_count(kal["state_names"])
    k_z = np.array(kal["K"])[:, len(kal["state_names"]) - nz:] if nz else None    # the integrators' own
    k_a = kalman.law_gain(si.K, si.K_w, dist, k_z)
    kal["K"] = k_a.tolist()
    kal["law"] = dict(kal["law"], M=fold(*(np.array(kal[key]) for key in ("A", "B", "C", "L")), k_a,
                                         kal["wheel_radius_m"], nz).tolist())
    out["generator"] = doc["generator"] + note
    return out


def _rounded(value):
    """Plain JSON types with floats rounded (_num), matrices as lists of rows."""
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _matrix(value) if value.ndim == 2 else [_num(v) for v in value]
    if isinstance(value, (list, tuple)):
        return [_rounded(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return _num(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def _is_matrix(value):
    return isinstance(value, list) and value and isinstance(value[0], list)


def _has_matrix(value):
    return isinstance(value, dict) and any(_is_matrix(v) or _has_matrix(v) for v in value.values())


def dumps(doc, indent="  "):
    """JSON text with one matrix row per line (readable diffs), keys in a fixed order: scalars
    and lists first, then objects holding matrices, then matrices."""
    def order(k):
        v = doc[k]
        return (2 if _is_matrix(v) else 1 if _has_matrix(v) else 0, k)
    lines = []
    for key in sorted(doc, key=order):
        value = doc[key]
        if _is_matrix(value):
            rows = ",\n".join(indent + "  " + json.dumps(row) for row in value)
            lines.append('%s%s: [\n%s\n%s]' % (indent, json.dumps(key), rows, indent))
        elif _has_matrix(value):
            lines.append("%s%s: %s" % (indent, json.dumps(key), dumps(value, indent + "  ").rstrip("\n")))
        else:
            lines.append("%s%s: %s" % (indent, json.dumps(key), json.dumps(value, sort_keys=True)))
    return "{\n" + ",\n".join(lines) + "\n" + indent[:-2] + "}\n"


def summary(g):
    st = g.structure
    ol = ", ".join("%.4g" % abs(z) for z in st["open_loop_eigenvalues"])
    return "\n".join([
        "variant %s: ts %.4g s, state units %s" % (g.variant.name, g.ts_s, "/".join(sorted(set(g.variant.state_units)))),
        "  controllability rank %d, observability rank %d (of 10)" % (st["controllability_rank"], st["observability_rank"]),
        "  open-loop |eig|: %s" % ol,
        "  closed-loop spectral radius of A - B K: %.6f" % spectral_radius(g.A - g.B @ g.K),
        "  detector eigenvalues (Abar - L1 C): %s" % ", ".join("%.4g" % z.real for z in g.detector_eigenvalues),
        "  Kalman filter: %d states (observability rank %d), slowest error mode |eig| %.5f"
        % (g.kalman.n, g.kalman.observability_rank, np.max(np.abs(g.kalman.filter_eigenvalues))),
        "  state feedback A - B K on each model, spectral radius: %s"
        % ", ".join("%.5f on %s" % (r, m) for m, r in sorted(g.state_feedback_radii.items())),
    ] + robustness_lines(g))


def robustness_lines(g):
    u = kalman.UncertaintySet.describe(not g.variant.paper_conventions)
    m = g.margins

    def at(w):
        if not isinstance(w[3], str):
            robot = "wheel radius x%g" % w[3]
        else:
            robot = w[3] if w[3] == kalman.PAYLOAD_LABEL else "the robot at the fit's %s" % w[3]
        return "%s model, duties %g ms into the tick, motor gain x%g, %s" % (w[0], w[1] * 1e3, w[2], robot)
    span = "both models, %s ms of delay, motor gain x%s, wheel radius x%s" % (
        "/".join("%g" % (d * 1e3) for d in u["delays_s"]), "/".join("%g" % v for v in u["input_gains"]),
        "/".join("%g" % v for v in u["wheel_radius_factors"])) + (
        ", %g kg at the top of link 3" % u["payload_kg_at_top_of_link_3"] if "payload_kg_at_top_of_link_3" in u else "")
    if g.spread is not None and g.spread.axes():
        span += ", the robots %g sigma along the %d loosest axes of the parameters' fit" % (
            g.spread.describe()["k_sigma"], len(g.spread.axes()))
    where = "worst radius %.5f (%s), least damping %.3f (%s)" % (m.radius, at(m.radius_at), m.damping, at(m.damping_at))
    if m.robust:
        return ["  joint weight x%g, wheel input weight x%g, filter input noise x%g: the loop holds %s" % (
            g.joint_weight_scale, g.r_wheel_scale, g.kalman.noise.input_noise_scale, span), "    " + where]
    return ["  WARNING: no wheel weight and filter input noise make the loop hold %s at ts %.4g s; using the "
            "plain design" % (span, g.ts_s), "    " + where]


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
    ap = argparse.ArgumentParser(prog=hostsim.command("gains"), description=__doc__.split("\n\n")[0])
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
        spread = load_spread(args.params)
        status = 0
        for name in names:
            g = design_gains(name, params, args.ts, spread=spread)
            print(summary(g))
            if spread is not None:
                lines, text = verdict.report(g, spread)
                print("\n".join(lines))
                print("  VERDICT: " + text)
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

