"""A reference governor for the paper's law: the robot is led back to its origin along a path
the motors can follow (scenario field ``reference_governor``; linear and nonlinear modes).

Section 7 starts the robot 0.1 rad off upright on all three links, at rest: the LQR then asks
about 20 V of the 7.6 V motors in the first tick, because it wants the tilt AND the wheel
position back at once. Catching a lean means rolling under it, and a bent robot can rest only
where its centre of mass is over the axle. The rest points (x_e, u_e) of the model, rates zero
and ``(A - I) x_e + B u_e = 0``, form a 4-dimensional family: the wheel positions, and the
bent poses held by constant joint torques. The governor moves the law's reference along them:

    u_k = kappa_k u_e - K (x^_k - kappa_k x_e) - K_w w^_k

* (x_e, u_e): the rest point for which the law, holding that reference from the first
  estimate x^_0, asks the least peak input over the horizon (a linear program on the
  closed-loop prediction u_j = u_e - K (A - B K)^j (x^_0 - x_e));
* kappa_k in [0, kappa_{k-1}] (kappa_0 = 1): each tick the smallest value whose prediction,
  holding it from the current estimate, keeps every input within ``limit_v`` for the horizon
  (the classic scalar reference governor of Gilbert and Kolmanovsky: the prediction is linear
  in kappa, so the admissible kappas form an interval). When none is admissible, kappa stays.

The prediction assumes the linear model and no disturbance: ``limit_v`` is the motors' 7.6 V
less a margin for what it does not know (the estimate's error, the disturbance compensation).
"""
import numpy as np
import scipy.linalg
import scipy.optimize

from tipbot_fw.vocabulary import ACTUATED_INPUTS

HORIZON_S = 6.0
MARGIN_V = 0.6


class ReferenceGovernor:
    """For SI gains g (tipbot_fw.gains.Gains) and the first estimate x^_0."""

    def __init__(self, g, xhat0, limit_v=None, horizon_s=HORIZON_S):
        act = list(ACTUATED_INPUTS)
        self.K = g.K[act]
        self.limit_v = g.u_max_v - MARGIN_V if limit_v is None else limit_v
        acl = g.A - g.B[:, act] @ self.K
        n = int(round(horizon_s / g.ts_s))
        h = np.zeros((n, len(act), 10))
        m = np.eye(10)
        for j in range(n):
            h[j] = self.K @ m
            m = acl @ m
        self.H = h.reshape(n * len(act), 10)            # u_j = u_ref - H_j (x - x_ref)
        self.n_u = len(act)
        self.x_e, self.u_e, self.peak0_v = rest_point(g, self.H, np.asarray(xhat0, dtype=float))
        self.u_e5 = np.zeros(5)
        self.u_e5[act] = self.u_e
        self.kappa = 1.0

    def reference(self, xhat):
        """The reference for this tick's estimate: (kappa_k x_e (10, SI), kappa_k u_e (5, V))."""
        a = -self.H @ xhat                   # u_j = a + kappa b
        b = self.H @ self.x_e + np.tile(self.u_e, len(self.H) // self.n_u)
        lo, hi = 0.0, self.kappa
        lim = self.limit_v
        pos, neg = b > 1e-12, b < -1e-12
        if pos.any():
            lo = max(lo, np.max((-lim - a[pos]) / b[pos]))
            hi = min(hi, np.min((lim - a[pos]) / b[pos]))
        if neg.any():
            lo = max(lo, np.max((lim - a[neg]) / b[neg]))
            hi = min(hi, np.min((-lim - a[neg]) / b[neg]))
        flat = ~(pos | neg)
        if lo <= hi and not np.any(np.abs(a[flat]) > lim):
            self.kappa = lo
        return self.kappa * self.x_e, self.kappa * self.u_e5


# Singular values of [(A - I) positions, B] below this fraction of the largest span the rest
# points (the ZOH model's are ~1e-13 of it: round-off of exact zeros; the others ~1e-2).
REST_RCOND = 1e-9


def rest_point(g, h, x):
    """The rest point (x_e, u_e) minimizing the peak predicted input max_j |u_e - H_j (x - x_e)|
    over the horizon (a linear program) -> (x_e (10), u_e (actuated), that peak)."""
    act = list(ACTUATED_INPUTS)
    eq = np.hstack([(g.A - np.eye(10))[:, :5], g.B[:, act]])     # (A - I) [p; 0] + B u = 0
    basis = scipy.linalg.null_space(eq, rcond=REST_RCOND)
    nz = basis.shape[1]
    xe_basis = np.vstack([basis[:5], np.zeros((5, nz))])
    ue_basis = basis[5:]
    reps = len(h) // len(act)
    hx = h @ x
    hz = h @ xe_basis + np.tile(ue_basis, (reps, 1))              # u_j = -hx + hz z
    a_ub = np.vstack([np.hstack([hz, -np.ones((len(hz), 1))]), np.hstack([-hz, -np.ones((len(hz), 1))])])
    b_ub = np.concatenate([hx, -hx])
    c = np.zeros(nz + 1)
    c[-1] = 1.0
    res = scipy.optimize.linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * nz + [(0, None)])
    z = res.x[:nz]
    return xe_basis @ z, ue_basis @ z, float(res.x[-1])
