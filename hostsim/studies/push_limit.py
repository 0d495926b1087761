"""Push limit: the largest push on link 3 that ANY controller within the input limit could recover.

``python -m hostsim push-limit [--gains FILE ...] [--horizons S ...] [--u-max-v V] [--validate]
[--out DIR]``

Issue 12 asked for 0.3 N s at link 3's centre of mass (the margin study's "push"); the LQR law
holds 0.19-0.22 N s. Whether a better law could do more is a question about the plant, not the
law: from which pushes can the upright equilibrium be recovered at all with |u_i| <= u_max on
the four motors?

**The push.** A horizontal impulse P at link 3's centre of mass on the upright robot at rest
is a jump of the generalized velocities, M^-1 J^T P (hostsim.world.plant.link_push_impulse, as
the simulator applies it): the post-push state is P x_p, linear in P.

**The bounds.** On the discrete model the gains file is designed on (x+ = A x + B u at ts_s,
SI), two linear programs in P and the inputs u_0..u_{N-1} maximize P over a horizon of N
ticks (scipy.optimize.linprog, HiGHS). Only A's unstable modes z = w' x (z+ = lambda z +
w' B u, |lambda| > 1) decide: the others decay by themselves once u = 0.

- *recoverable* (a lower bound): every unstable mode is zero at N; from there u = 0 lets the
  robot settle upright (the wheels wherever they stopped, as the margin study allows);
- *certain loss* (an upper bound): every unstable mode at N is within what an infinite
  horizon could still bring back, |z_N| <= umax ||w' B||_1 / (|lambda| - 1) (the geometric
  series of the largest inputs): necessary, so beyond this P no controller, however clever,
  recovers the linear model.

The recoverable bound grows with N, the certain-loss bound shrinks, and they meet: the
unstable modes' time constants are 0.1-0.2 s, so 2 s settles the answer. The bound is
proportional to u_max (the LPs scale) as long as no state limit binds.

**Joint limits.** With them the angles also stay within the firmware's stop limits
(limits.th1_rad, th2_rad, th3_rad of the default firmware config) at every tick, and the
recoverable LP asks the robot at rest and upright at N (so that it stays within them after):
the states become variables, and the solver holds them only up to 2 s horizons
(STATE_LP_MAX_HORIZON_S). The table gives the bounds with and without.

**Late plans** (hostsim.studies.push_plan): the firmware sees a push one tick after it at the
earliest, and its law acts on an estimate that has not yet seen it meanwhile; a plan started j
ticks after the push, the law acting before, duties landing 0 or 2 ms into the tick, ending
where the law takes over without saturating, recovers less: the table "a plan started j
ticks after the push" (``--no-late`` leaves it out).

**Validation** (``--validate``): at 95 % of the recoverable bound of the physical model, each
direction, the joint-limited LP's plan (made with 97 % of u_max, the rest left for feedback) is
tracked on the nonlinear plant (u = sat(u_plan - K (x - x_plan)), exact state), then the LQR
law holds the robot where the plan left it; the same push with the LQR law alone beside it.
"""
import argparse
import json
import os
import sys
import time

import hostsim
import numpy as np

from hostsim.paths import REPO_ROOT, out_dir

DEFAULT_GAINS = ("gains/paper.json", "gains/physical.json")
DEFAULT_HORIZONS_S = (0.5, 1.0, 2.0, 4.0)
# The joint-limit LPs carry the states, which the solver cannot hold beyond this (max_push).
STATE_LP_MAX_HORIZON_S = 2.0
TARGET_N_S = 0.3                      # issue 12
PUSH_LINK = 3
ANGLES = (2, 3, 4)                    # th1, th2, th3 in the state
AT_REST = slice(2, 10)                # angles and rates: the wheels' positions are free
UPRIGHT_LIMIT_RAD = np.radians(30.0)  # hostsim.sim.metrics' criterion, restated for the linear check
FINAL_TH1_RAD = 0.1                   # hostsim.studies.montecarlo.FINAL_TH1_RAD, likewise
VALIDATE_FRACTION = 0.95
PLAN_INPUT_FRACTION = 0.97


def load_design(gains_path, u_max_v=None):
    """-> dict: the gains' discrete model (SI), the law, the input limit, the push direction and
    the Kalman block (filter and law, tipbot_fw.gains.KalmanGains)."""
    from hostsim.model.equations import RobotModel, state_scale_to_si
    from hostsim.world.plant import link_push_impulse
    from tipbot_fw.gains import load_gains_document

    doc, g = load_gains_document(gains_path)
    model = RobotModel(doc["model_variant"], doc["parameters"])
    q = np.zeros(5)
    x_push = np.zeros(10)
    x_push[5:] = (np.linalg.solve(model.mass_matrix(q), np.asarray(link_push_impulse(model, q, PUSH_LINK, 1.0)))
                  * np.diag(state_scale_to_si(model.variant))[5:])
    act = list(g.actuated_inputs)
    return {"variant": g.model_variant, "ts_s": g.ts_s, "A": g.A, "B": g.B[:, act], "K": g.K[act],
            "u_max_v": float(g.u_max_v if u_max_v is None else u_max_v), "x_push": x_push, "model": model,
            "actuated": act, "kalman": g.kalman}


def unstable_modes(a, b, u_max_v):
    """[(lambda, w, radius)]: A's modes with |lambda| > 1, their left eigenvectors w (complex)
    and the largest |w' x| from which an infinite horizon of |u| <= u_max can still bring the
    mode back (sum over k of |lambda|^-(k+1) u_max ||w' B||_1)."""
    lam, vl = np.linalg.eig(a.T)
    return [(lam[i], vl[:, i], u_max_v * np.sum(np.abs(vl[:, i] @ b)) / (abs(lam[i]) - 1.0))
            for i in np.flatnonzero(np.abs(lam) > 1.0 + 1e-9)]


def _parts(row, lam):
    """The real rows of a mode's constraint: a complex pair's real and imaginary parts (each
    within the modulus bound: a relaxation, still an upper bound)."""
    return [row.real, row.imag] if abs(lam.imag) > 1e-12 else [row.real]


class LPFailed(RuntimeError):
    """The LP solver gave up (long horizons with joint limits: see max_push)."""


def max_push(d, horizon_s, mode, joint_limits=None, sign=1.0, u_frac=1.0):
    """The largest push (N s, >= 0) in direction sign for one LP (see the module docstring).

    mode "recover" or "loss"; joint_limits: (th1, th2, th3) rad bounds at every tick, or None;
    u_frac: the inputs within u_frac u_max. -> (push_n_s, u (N x 4), x (N+1 x 10)): x the LP's
    states with joint limits; without, the model run forward from the push with u, which near
    the end of a long horizon shows the solver's tolerance amplified by the unstable modes.

    Without joint limits only the unstable modes are written, lambda^-N z_N = z_0 +
    sum_k lambda^-(k+1) w' B u_k: decaying coefficients, well conditioned at any horizon. Joint
    limits need the states as variables, linked by the dynamics, whose rounding the unstable
    modes amplify by up to 1.06^N: HiGHS gives up beyond about 2 s (LPFailed)."""
    a, b, x_p = d["A"], d["B"], sign * d["x_push"]
    steps = int(round(horizon_s / d["ts_s"]))
    umax = d["u_max_v"] * u_frac
    if mode not in ("recover", "loss"):
        raise ValueError("mode must be 'recover' or 'loss', got %r" % (mode,))
    if joint_limits is not None:
        return _state_lp(a, b, x_p, steps, mode, umax, joint_limits)
    p, u = _modal_lp(a, b, x_p, steps, mode, umax)
    x = [p * x_p]
    for uk in u:
        x.append(a @ x[-1] + b @ uk)
    return p, u, np.array(x)


def _modal_lp(a, b, x_p, steps, mode, umax):
    """Variables [P, u_0..u_{N-1}]; each unstable mode scaled by lambda^-N."""
    eqs, ubs, rhs = [], [], []
    for lam, w, radius in unstable_modes(a, b, umax):
        row = np.concatenate([[w @ x_p], np.concatenate([lam ** -(k + 1) * (w @ b) for k in range(steps)])])
        for part in _parts(row, lam):
            if mode == "recover":
                eqs.append(part)
            else:
                ubs += [part, -part]
                rhs += [abs(lam) ** -steps * radius] * 2
    nv = 1 + b.shape[1] * steps
    res = _solve(nv, eqs, ubs, rhs, [(-umax, umax)] * (nv - 1), mode)
    return float(res.x[0]), res.x[1:].reshape(steps, b.shape[1])


def _state_lp(a, b, x_p, steps, mode, umax, joint_limits):
    """Variables [P, u_0..u_{N-1}, x_1..x_N], the dynamics as equalities."""
    from scipy import sparse

    n, m = b.shape
    ix = 1 + m * steps
    nv = ix + n * steps
    col_p = np.zeros((n * steps, 1))
    col_p[:n, 0] = -a @ x_p               # x_1 - A (P x_p) - B u_0 = 0
    dyn = sparse.hstack([sparse.csr_matrix(col_p), -sparse.kron(sparse.identity(steps), b),
                         sparse.identity(n * steps) - sparse.kron(sparse.eye(steps, k=-1), a)]).tocsr()
    last = np.zeros((n, nv))
    last[:, nv - n:] = np.eye(n)
    eqs, ubs, rhs = [dyn], [], []
    if mode == "recover":
        eqs.append(sparse.csr_matrix(last[AT_REST]))
    else:
        for lam, w, radius in unstable_modes(a, b, umax):
            for part in _parts(w @ last, lam):
                ubs += [part, -part]
                rhs += [radius] * 2
    box = [(None, None)] * n
    for i, lim in zip(ANGLES, joint_limits):
        box[i] = (-lim, lim)
    res = _solve(nv, eqs, ubs, rhs, [(-umax, umax)] * (m * steps) + box * steps, mode)
    return float(res.x[0]), res.x[1:ix].reshape(steps, m), np.vstack([res.x[0] * x_p, res.x[ix:].reshape(steps, n)])


def _solve(nv, eqs, ubs, rhs, bounds, mode):
    """max P (the first variable, >= 0) subject to eqs = 0 and ubs <= rhs."""
    from scipy import sparse
    from scipy.optimize import linprog

    a_eq = None
    if eqs:
        a_eq = sparse.vstack([e if sparse.issparse(e) else sparse.csr_matrix(np.atleast_2d(e)) for e in eqs])
    a_ub = sparse.csr_matrix(np.array(ubs)) if ubs else None
    c = np.zeros(nv)
    c[0] = -1.0
    for method in ("highs", "highs-ipm"):     # long horizons are degenerate: the simplex may give up
        res = linprog(c, A_ub=a_ub, b_ub=rhs or None, A_eq=a_eq,
                      b_eq=None if a_eq is None else np.zeros(a_eq.shape[0]), bounds=[(0.0, None)] + bounds,
                      method=method)
        if res.status in (0, 3):
            break
    if res.status == 3:
        raise ValueError("the %s LP is unbounded: the push does not excite an unstable mode" % mode)
    if res.status != 0:
        raise LPFailed("the %s LP: %s" % (mode, res.message))
    return res


def lqr_linear_recovers(d, push_n_s, duration_s=5.0):
    """The gains' state feedback, saturated, with the exact state on the linear model: does it
    recover the push by the margin study's criterion (|th1| below 30 degrees, ending below
    0.1 rad)? Diverging runs are cut once th1 leaves the criterion."""
    a, b, k, umax = d["A"], d["B"], d["K"], d["u_max_v"]
    x = push_n_s * d["x_push"]
    for _ in range(int(round(duration_s / d["ts_s"]))):
        x = a @ x + b @ np.clip(-k @ x, -umax, umax)
        if abs(x[2]) >= UPRIGHT_LIMIT_RAD:
            return False
    return abs(x[2]) < FINAL_TH1_RAD


def lqr_linear_limit(d, sign=1.0, hi=2.0, tol=1e-3):
    """Bisection: the largest push (N s) the saturated LQR law recovers on the linear model."""
    sd = dict(d, x_push=sign * d["x_push"])
    lo = 0.0
    if lqr_linear_recovers(sd, hi):
        return hi
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if lqr_linear_recovers(sd, mid) else (lo, mid)
    return lo


def validate_nonlinear(d, horizon_s, sign=1.0, fraction=VALIDATE_FRACTION, settle_s=3.0):
    """At fraction x the recoverable bound, track the LP's plan on the nonlinear plant (exact
    state, 1 ms RK4, u = sat(u_plan - K (x - x_plan))), then hold with the LQR law around where
    the plan stops; and the LQR law alone from the same push. -> dict: the push and, for each,
    the peak and final |th1| and whether it recovered by the margin study's criterion."""
    from hostsim.model.equations import state_scale_to_si
    from hostsim.world.plant import Plant, link_push_impulse

    bound = max_push(d, horizon_s, "recover", sign=sign)[0]
    push = fraction * bound
    u_plan, x_plan = _plan_at(d, horizon_s, sign * push)
    to_si = np.diag(state_scale_to_si(d["model"].variant))
    act, umax, k = d["actuated"], d["u_max_v"], d["K"]
    out = {"push_n_s": sign * push, "recoverable_n_s": bound, "horizon_s": horizon_s,
           "plan_input_fraction": PLAN_INPUT_FRACTION}
    for name, planned in (("plan then LQR", True), ("LQR alone", False)):
        plant = Plant(d["model"], np.zeros(10), dt_s=1e-3)
        plant.apply_impulse(link_push_impulse(plant.model, plant.x[:5], PUSH_LINK, sign * push))
        th1 = []
        for j in range(len(u_plan) + int(round(settle_s / d["ts_s"]))):
            x = plant.x * to_si
            th1.append(abs(x[2]))
            if th1[-1] > np.pi / 2:
                break
            if planned and j < len(u_plan):
                u4 = u_plan[j] - k @ (x - x_plan[j])
            else:
                u4 = -k @ (x - (x_plan[-1] if planned else 0.0))
            u = np.zeros(5)
            u[act] = np.clip(u4, -umax, umax)
            plant.advance(u, d["ts_s"])
        out[name] = {"peak_abs_th1_rad": float(max(th1)), "final_abs_th1_rad": float(th1[-1]),
                     "recovered": bool(max(th1) < UPRIGHT_LIMIT_RAD and th1[-1] < FINAL_TH1_RAD)}
    return out


def _plan_at(d, horizon_s, push_n_s):
    """The recoverable LP's inputs (within PLAN_INPUT_FRACTION of u_max, the rest left to the
    tracking feedback) and states for this push (the LP with the states and the joint limits,
    at rest at its end). With x_push scaled by the push the LP's largest P is >= 1 if the push
    is recoverable, and its solution scaled by 1/P is a plan for the push itself (x_0 scales
    with P; the constraints are linear, hold 0, and a box shrunk by 1/P stays inside)."""
    p, u, x = max_push(dict(d, x_push=d["x_push"] * push_n_s), min(horizon_s, STATE_LP_MAX_HORIZON_S), "recover",
                       stop_limits(), u_frac=PLAN_INPUT_FRACTION)
    if p < 1.0:
        raise ValueError("a push of %.3f N s is beyond the plan's bound (%.3f N s)" % (push_n_s, p * push_n_s))
    return u / p, x / p


def stop_limits():
    """(th1, th2, th3) rad: the default firmware config's stop limits."""
    from hostsim.studies.roa import angle_limits
    lim = angle_limits()
    return lim["th1"], lim["th2"], lim["th3"]


def run_push_limit(gains_paths=DEFAULT_GAINS, horizons_s=DEFAULT_HORIZONS_S, u_max_v=None, validate=False,
                   late=True):
    """-> {"rows": [...], "lqr": [...], "late": [...] (None without late or with u_max_v: the late
    plans are made for the gains' own u_max), "validation": [one per direction] or None,
    "_meta": {...}}."""
    from hostsim.studies import push_plan
    joint_limits = stop_limits()
    t0 = time.perf_counter()
    rows, lqr, validation = [], [], None
    late_rows = [] if late and u_max_v is None else None
    for path in gains_paths:
        path = path if os.path.isabs(path) else os.path.join(REPO_ROOT, path)
        d = load_design(path, u_max_v)
        for sign in (1.0, -1.0):
            lqr.append({"variant": d["variant"], "sign": sign, "lqr_linear_n_s": lqr_linear_limit(d, sign)})
            for limits in (None, joint_limits):
                for h in horizons_s:
                    row = {"variant": d["variant"], "sign": sign, "joint_limits": limits is not None, "horizon_s": h}
                    for key, mode in (("recoverable_n_s", "recover"), ("certain_loss_n_s", "loss")):
                        skip = limits is not None and h > STATE_LP_MAX_HORIZON_S
                        row[key] = None if skip else max_push(d, h, mode, limits, sign)[0]
                    rows.append(row)
        if late_rows is not None and d["kalman"] is not None:      # the plans start after the filter's law
            late_rows += push_plan.late_bounds(_solve, d, d["kalman"], joint_limits)
        if validate and d["variant"] == "physical":
            validation = [validate_nonlinear(d, min(max(horizons_s), STATE_LP_MAX_HORIZON_S), sign)
                          for sign in (1.0, -1.0)]
    return {"rows": rows, "lqr": lqr, "late": late_rows, "validation": validation,
            "_meta": {"generator": __name__, "target_n_s": TARGET_N_S, "link": PUSH_LINK, "joint_limits_rad": list(joint_limits),
                      "u_max_v": u_max_v, "gains": list(gains_paths), "wall_s": time.perf_counter() - t0}}


def table(res):
    head = ["model", "dir", "joint limits", "horizon s", "recoverable N s", "certain loss N s"]
    rows = [[r["variant"], "+" if r["sign"] > 0 else "-", "yes" if r["joint_limits"] else "no",
             "%g" % r["horizon_s"], _num(r["recoverable_n_s"]), _num(r["certain_loss_n_s"])]
            for r in res["rows"]]
    return _columns(head, rows)


def late_table(res):
    head = ["model", "duties land ms", "plan starts (ticks after the push)", "recoverable N s"]
    rows = [[r["variant"], "%g" % (1000 * r["delay_s"]), str(r["start_tick"]), _num(r["recoverable_n_s"])]
            for r in res["late"]]
    return _columns(head, rows)


def _columns(head, rows):
    widths = [max(len(str(c)) for c in col) for col in zip(head, *rows)]
    fmt = "  ".join("%%-%ds" % w for w in widths)
    return "\n".join(fmt % tuple(r) for r in [head] + rows)


def _num(v):
    return "-" if v is None else "%.3f" % v


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("push-limit"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--gains", nargs="+", default=list(DEFAULT_GAINS),
                    help="gains files whose discrete model is studied (default gains/paper.json gains/physical.json)")
    ap.add_argument("--horizons", nargs="+", type=float, default=list(DEFAULT_HORIZONS_S),
                    help="LP horizons in s (default 0.5 1 2 4; with joint limits only up to %g): the two bounds "
                    "must agree at the longest" % STATE_LP_MAX_HORIZON_S)
    ap.add_argument("--u-max-v", type=float, default=None,
                    help="the input limit in V (default: each gains file's u_max_v)")
    ap.add_argument("--validate", action="store_true",
                    help="also track the LP's plan on the nonlinear physical plant at %g %%%% of the bound"
                    % (100 * VALIDATE_FRACTION))
    ap.add_argument("--no-late", action="store_true",
                    help="leave out the plans started after the push (hostsim.studies.push_plan)")
    ap.add_argument("--out", default=out_dir("push_limit"), help="output directory (default out/push_limit)")
    args = ap.parse_args(argv)
    if any(not h > 0 for h in args.horizons):
        ap.error("--horizons must be positive")
    if args.u_max_v is not None and not args.u_max_v > 0:
        ap.error("--u-max-v must be positive")
    from tipbot_fw.gains import GainsError
    try:
        res = run_push_limit(args.gains, args.horizons, args.u_max_v, args.validate, not args.no_late)
    except GainsError as exc:
        print("python -m hostsim push-limit: %s" % exc, file=sys.stderr)
        return 2
    print("The largest push on link %d's centre of mass any controller with |u| <= u_max recovers "
          "(linear model; target %g N s)" % (PUSH_LINK, TARGET_N_S))
    print(table(res))
    if any(r["recoverable_n_s"] is None for r in res["rows"]):
        print("-: the joint-limited LPs stop at %g s horizons (the solver cannot hold the states beyond)"
              % STATE_LP_MAX_HORIZON_S)
    for r in res["lqr"]:
        print("the gains' LQR law, saturated, exact state, linear model, %s (%s): %.3f N s"
              % (r["variant"], "+" if r["sign"] > 0 else "-", r["lqr_linear_n_s"]))
    if res["late"]:
        from hostsim.studies.push_plan import END_INPUT_FRACTION, HORIZON_S
        print("A plan started j ticks after the push (the law acting before it; %g s, then the law within %g %% of "
              "u_max; one direction: the linear model is symmetric)" % (HORIZON_S, 100 * END_INPUT_FRACTION))
        print(late_table(res))
    for v in res["validation"] or ():
        print("nonlinear physical plant, push %+.3f N s (%g %% of the bound): plan then LQR peak |th1| %.3f rad "
              "(%s); LQR alone peak |th1| %.3f rad (%s)"
              % (v["push_n_s"], 100 * VALIDATE_FRACTION, v["plan then LQR"]["peak_abs_th1_rad"],
                 "recovers" if v["plan then LQR"]["recovered"] else "falls",
                 v["LQR alone"]["peak_abs_th1_rad"], "recovers" if v["LQR alone"]["recovered"] else "falls"))
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "push_limit.json")
    with open(path, "w") as f:
        json.dump(res, f, indent=1, sort_keys=True)
    print("wrote %s (%.0f s)" % (path, res["_meta"]["wall_s"]))
    return 0
