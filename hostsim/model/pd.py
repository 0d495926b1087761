"""The PD baseline of Appendix D, designed here (the paper gives no gains, no structure).

Structure (each motor sees only what a hand-tuned PD would):
- both wheels: u = -(sum_i kp_i th_i + kd_i th_i' + kp_m d_m + kd_m d_m') -+ (kp_s d_s + kd_s d_s'),
  a PD on the three link angles (a PD on th1 alone cannot hold links 2 and 3 up), a PD on
  the mean wheel displacement d_m = (d_r + d_l)/2 (without it the robot drifts away), and
  the usual steering PD on the difference d_s = d_r - d_l (the mean and the difference need
  gains of opposite signs, so a PD on each wheel's own displacement cannot stabilize);
- joint 2: u = -(kp_2 th2 + kd_2 th2'); joint 3: u = -(kp_3 th3 + kd_3 th3').
The fourteen gains minimize the same quadratic cost as the LQR (the paper's Q, R), evaluated
exactly as trace(X) with X = Acl' X Acl + Q + K' R K (a discrete Lyapunov equation), by
Nelder-Mead: first the spectral radius from the LQR's corresponding entries (which alone
do not stabilize), then the cost from the first stabilizing point. So the comparison is
like-for-like: the best PD of this structure for the very cost the LQR minimizes.

The design runs in the gains file's own units (cm for the paper variant), from its A, B, Q,
R and K, so each gains file gets its own PD (``pd_for_gains``, cached under .cache/pd/ by the
hash of the gains file and of this module; ``python -m hostsim pd [GAINS]`` prints it). Its
cost is ~20 % (paper) and ~4 % (physical) above the LQR's: close to optimal without a
disturbance. What the PD lacks is the disturbance compensation: no K_w w^ term and no
integral action, so a constant input disturbance shifts its equilibrium, where the optimal
controller cancels the disturbance one tick after the detector sees it. That is the
difference Appendix D shows.

Where the baseline runs:
- linear and nonlinear modes: u = -K_pd y, the measurement itself (hostsim.sim.linear_sim);
- firmware in the loop: the firmware has one law, u = -K x~ - K_w w^, so it is given a
  gains document with K = K_pd and K_w = 0 (hostsim.sim.firmware_build.pd_gains_document): the PD acts on
  the estimate x~, which equals y after a few ticks (detector poles at 0.2; with C = I and
  L2 = E G_w the estimate's error does not depend on the disturbance).
"""
import argparse
import hashlib
import json
import os

import hostsim
import numpy as np
from scipy.linalg import solve_discrete_lyapunov
from scipy.optimize import minimize

from hostsim.errors import DesignError
from hostsim.model import design
from hostsim.paths import CACHE_DIR as _CACHE, GAINS_DIR, REPO_ROOT
from tipbot_fw.cores.kalman_design import spectral_radius
from tipbot_fw.gains import load_gains_document

CACHE_DIR = os.path.join(_CACHE, "pd")

# For each free gain, the (row of K, column of x, coefficient) cells it fills.
LAYOUT = (
    (((0, 2, 1), (1, 2, 1)), "kp_th1"), (((0, 7, 1), (1, 7, 1)), "kd_th1"),
    (((0, 3, 1), (1, 3, 1)), "kp_w_th2"), (((0, 8, 1), (1, 8, 1)), "kd_w_th2"),
    (((0, 4, 1), (1, 4, 1)), "kp_w_th3"), (((0, 9, 1), (1, 9, 1)), "kd_w_th3"),
    (((0, 0, .5), (0, 1, .5), (1, 0, .5), (1, 1, .5)), "kp_mean"),
    (((0, 5, .5), (0, 6, .5), (1, 5, .5), (1, 6, .5)), "kd_mean"),
    (((0, 0, 1), (0, 1, -1), (1, 0, -1), (1, 1, 1)), "kp_steer"),
    (((0, 5, 1), (0, 6, -1), (1, 5, -1), (1, 6, 1)), "kd_steer"),
    (((3, 3, 1),), "kp_th2"), (((3, 8, 1),), "kd_th2"),
    (((4, 4, 1),), "kp_th3"), (((4, 9, 1),), "kd_th3"),
)


def pd_matrix(gains):
    k = np.zeros((5, 10))
    for (cells, _), value in zip(LAYOUT, gains):
        for r, c, coef in cells:
            k[r, c] += coef * value
    return k


# A closed loop closer to the unit circle than this has (numerically) unbounded cost; the
# Lyapunov solution there is meaningless, and a PD that leaves the wheel position free
# would otherwise look optimal.
STABILITY_MARGIN = 1e-4


def lq_cost(a, b, q, r, k):
    """trace of the closed loop's cost-to-go matrix (inf if not stable with margin)."""
    acl = a - b @ k
    if np.max(np.abs(np.linalg.eigvals(acl))) >= 1.0 - STABILITY_MARGIN:
        return np.inf
    x = solve_discrete_lyapunov(acl.T, q + k.T @ r @ k)
    cost = float(np.trace(x))
    return cost if cost > 0 else np.inf


def closed_loop_radius(a, b, k):
    return spectral_radius(a - b @ k)


def design_pd(a, b, q, r, k_lqr):
    """Structured PD gains (5x10) minimizing the LQ cost; all matrices in one unit system.

    Returns (K_pd, named gains, cost).
    """
    # Least-squares projection of the LQR gain on the PD structure.
    basis = np.array([pd_matrix(np.eye(len(LAYOUT))[i]).ravel() for i in range(len(LAYOUT))]).T
    start = np.linalg.lstsq(basis, k_lqr.ravel(), rcond=None)[0]
    scale = np.where(np.abs(start) > 0, np.abs(start), 1.0)
    z = start / scale
    opts = dict(maxiter=6000, xatol=1e-7, fatol=1e-10, adaptive=True)
    if not np.isfinite(lq_cost(a, b, q, r, pd_matrix(z * scale))):
        res = minimize(lambda v: closed_loop_radius(a, b, pd_matrix(v * scale)), z, method="Nelder-Mead", options=opts)
        z = res.x
        if not np.isfinite(lq_cost(a, b, q, r, pd_matrix(z * scale))):
            raise DesignError("no stabilizing PD gains of this structure found (best spectral radius %.4f)" % res.fun)
    res = minimize(lambda v: lq_cost(a, b, q, r, pd_matrix(v * scale)), z, method="Nelder-Mead", options=opts)
    k = pd_matrix(res.x * scale)
    return k, dict(zip((name for _, name in LAYOUT), res.x * scale)), res.fun


def pd_for_gains(path):
    """The PD baseline for a gains file: dict(K (5x10, file units), gains (named), cost, lqr_cost).

    Cached: the Nelder-Mead search takes several seconds.
    """
    doc, gains = load_gains_document(path)      # the file's units: the PD is designed in them
    with open(__file__, "rb") as f:
        key = hashlib.sha256(gains.sha256.encode("ascii") + f.read()).hexdigest()[:16]
    cache = os.path.join(CACHE_DIR, "%s.json" % key)
    if os.path.exists(cache):
        with open(cache) as f:
            return json.load(f)
    a, b, q, r, k_lqr = (np.array(doc[n], dtype=float) for n in ("A", "B", "Q", "R", "K"))
    k, named, cost = design_pd(a, b, q, r, k_lqr)
    # the reference is the LQR of this very cost: the file's own law where it is that (the paper
    # variant), not a law with integral action, which minimizes a cost of its integrators too
    k_opt = design.dlqr(a, b, q, r, doc["actuated_inputs"])[0]
    out = dict(K=k.tolist(), gains={n: float(v) for n, v in named.items()}, cost=float(cost),
               lqr_cost=lq_cost(a, b, q, r, k_opt), spectral_radius=closed_loop_radius(a, b, k),
               units=doc["state_units"], gains_file=os.path.relpath(path, REPO_ROOT))
    os.makedirs(CACHE_DIR, exist_ok=True)
    tmp = cache + ".tmp%d" % os.getpid()
    with open(tmp, "w") as f:
        json.dump(out, f, indent=1)
    os.replace(tmp, cache)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("pd"), description=__doc__.split("\n\n")[0])
    ap.add_argument("gains", nargs="*", metavar="GAINS",
                    help="gains files (default gains/paper.json gains/physical.json)")
    paths = ap.parse_args(argv).gains or [os.path.join(GAINS_DIR, v + ".json") for v in ("paper", "physical")]
    for path in paths:
        pd = pd_for_gains(path)
        print("%s: PD cost %.6g, LQR cost %.6g (x%.3f), spectral radius %.5f"
              % (pd["gains_file"], pd["cost"], pd["lqr_cost"], pd["cost"] / pd["lqr_cost"], pd["spectral_radius"]))
        for name, value in pd["gains"].items():
            print("  %-9s %12.5g" % (name, value))
    return 0

