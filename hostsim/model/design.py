"""Discretization, optimal control and the robust disturbance detector (paper Sections 5-6).

Notation as in the paper: x_{k+1} = A x_k + B u_k + E w_k, y_k = C x_k, with input
disturbances E = B (w in volts). Functions take and return numpy arrays; a design that
cannot be carried out raises ``DesignError`` with the reason.
"""
import control
import numpy as np

from hostsim.errors import DesignError
from hostsim.model.equations import state_scale_to_si

# Section 7: Q = diag(20, 20, 1e7, 1, ..., 1), R = diag(50, 50, 50, 5000, 5000), in the
# paper's units (d in cm). The extraction lost the exponent's sign; 1e+7 is the one whose
# DARE gain equals the printed K (and "a higher weighting factor was given to ... the
# pendulum angle").
PAPER_Q_DIAG_CM = (20.0, 20.0, 1e7, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
PAPER_R_DIAG = (50.0, 50.0, 50.0, 5000.0, 5000.0)
DEFAULT_DETECTOR_POLE = 0.2


def _check_matrix(name, m, rows, cols):
    m = np.asarray(m, dtype=float)
    if m.shape != (rows, cols):
        raise DesignError("matrix %s has shape %dx%d, expected %dx%d" % ((name,) + m.shape + (rows, cols)))
    if not np.all(np.isfinite(m)):
        raise DesignError("matrix %s has non-finite entries" % name)
    return m


def discretize(ac, bc, ts_s):
    """Zero-order-hold discretization at period ts_s (python-control)."""
    if not ts_s > 0:
        raise DesignError("sampling period must be positive, got %r" % ts_s)
    n, m = bc.shape
    sysd = control.ss(ac, bc, np.eye(n), np.zeros((n, m))).sample(ts_s, method="zoh")
    return np.asarray(sysd.A), np.asarray(sysd.B)


def discrete_model_si(model, ts_s):
    """Discrete (A, B) of a hostsim.model.RobotModel at ts_s, with the state in SI units."""
    ac, bc = model.linearize()
    a, b = discretize(ac, bc, ts_s)
    t = state_scale_to_si(model.variant)
    return t @ a @ np.linalg.inv(t), t @ b


def structure_report(a, b, c, actuated):
    """Controllability/observability ranks and open-loop eigenvalues."""
    b_act = b[:, list(actuated)]
    return {
        "controllability_rank": int(np.linalg.matrix_rank(control.ctrb(a, b_act))),
        "observability_rank": int(np.linalg.matrix_rank(control.obsv(a, c))),
        "open_loop_eigenvalues": sorted(np.linalg.eigvals(a), key=lambda z: (abs(z), z.real)),
    }


def weights_in_units(q_diag_cm, r_diag, scale_to_cm):
    """Re-express the paper's Q (d in cm) for a state whose d unit is scale_to_cm cm.

    x_cm = S x, so x_cm' Q x_cm = x' (S Q S) x: the same physical deviation costs the same.
    """
    s = np.diag(scale_to_cm)
    return s @ np.diag(q_diag_cm) @ s, np.diag(np.asarray(r_diag, dtype=float))


def check_weights(q, r):
    n = q.shape[0]
    _check_matrix("Q", q, n, n)
    if not np.allclose(q, q.T) or np.min(np.linalg.eigvalsh((q + q.T) / 2)) < -1e-12 * max(1.0, np.abs(q).max()):
        raise DesignError("Q must be symmetric positive semi-definite")
    if not np.allclose(r, r.T):
        raise DesignError("R must be symmetric")
    ev = np.linalg.eigvalsh((r + r.T) / 2)
    if ev.min() <= 0:
        raise DesignError("R is singular or indefinite (smallest eigenvalue %.3g): every input needs a positive weight" % ev.min())


def check_inputs(b, actuated):
    """Actuated columns of B must act; the others (link 1) must be exactly zero."""
    for j in range(b.shape[1]):
        col = np.abs(b[:, j]).max()
        if j in actuated and col == 0.0:
            raise DesignError("input column %d of B is zero: that input cannot act (uncontrollable input)" % j)
        if j not in actuated and col != 0.0:
            raise DesignError("input column %d of B should be zero (unactuated) but is not" % j)


def dlqr(a, b, q, r, actuated):
    """Steady-state discrete LQR: (K, P, closed-loop eigenvalues), u = -K x."""
    n, m = b.shape
    _check_matrix("A", a, n, n)
    _check_matrix("R", r, m, m)
    check_inputs(b, actuated)
    check_weights(q, r)
    rank = np.linalg.matrix_rank(control.ctrb(a, b[:, list(actuated)]))
    if rank < n:
        raise DesignError("(A, B) is not controllable: controllability rank %d < %d" % (rank, n))
    try:
        k, p, e = control.dlqr(a, b, q, r)
    except Exception as exc:  # python-control raises several types (ValueError, LinAlgError, slycot errors)
        raise DesignError("discrete Riccati equation has no stabilizing solution: %s" % exc)
    return np.asarray(k), np.asarray(p), np.asarray(e)


def disturbance_gain(a, b, q, r, k, p, e_mat):
    """K_w for u = -K x - K_w w with w a constant input disturbance.

    From Section 5.2's recursion h_k = (A - B K)' (P E w_k + h_{k+1}) and
    u_k = -K x_k - K_v (P E w_k + h_{k+1}), K_v = (R + B'PB)^-1 B'. With w constant the
    recursion's fixed point is h = (I - Acl')^-1 Acl' P E w, so
    u = -K x - K_v (I - Acl')^-1 P E w.
    """
    acl = a - b @ k
    n = a.shape[0]
    k_v = np.linalg.solve(r + b.T @ p @ b, b.T)
    return k_v @ np.linalg.solve(np.eye(n) - acl.T, p @ e_mat)


def integrator_model(a, b, ts_s, rows=(0, 1)):
    """(A_z, B_z) of the model with integrators of the states `rows` (the wheel positions),
    z_{k+1} = z_k + ts x_rows,{k+1} = z_k + ts (A x_k + B u_k)[rows]: the integrator of the
    position reached, as the firmware's integrates its estimate of this tick."""
    n, nz = a.shape[0], len(rows)
    az = np.zeros((n + nz, n + nz))
    az[:n, :n] = a
    az[n:, :n] = ts_s * a[list(rows)]
    az[n:, n:] = np.eye(nz)
    return az, np.vstack([b, ts_s * b[list(rows)]])


def dlqi(a, b, q, r, actuated, ts_s, q_z, rows=(0, 1)):
    """LQR with integral action on the states `rows`: (K (m x n), K_z (m x len(rows)), P, closed
    loop eigenvalues) of u = -K x - K_z z on integrator_model, with the weight q_z on each z."""
    az, bz = integrator_model(a, b, ts_s, rows)
    n = a.shape[0]
    qz = np.zeros(az.shape)
    qz[:n, :n] = q
    qz[n:, n:] = np.eye(len(rows)) * q_z
    k, p, e = dlqr(az, bz, qz, r, actuated)
    return k[:, :n], k[:, n:], p, e


def finite_horizon_lqr(a, b, q, r, q_final, w_seq=None, e_mat=None, horizon=None):
    """Finite-horizon LQR with known disturbances (Section 5.2), solved backwards.

    Returns (K_seq, ff_seq, P_seq): u_k = -K_seq[k] x_k + ff_seq[k], k = 0..N-1, with
    ff_k = -K_v,k (P_{k+1} E w_k + h_{k+1}) and h_k = Acl_k' (P_{k+1} E w_k + h_{k+1}), h_N = 0.
    """
    n, m = b.shape
    if w_seq is None:
        if horizon is None:
            raise DesignError("finite_horizon_lqr needs a horizon or a disturbance sequence")
        w_seq = np.zeros((horizon, 1))
        e_mat = np.zeros((n, 1))
    w_seq = np.asarray(w_seq, dtype=float)
    horizon = w_seq.shape[0]
    p_next = np.asarray(q_final, dtype=float)
    h_next = np.zeros(n)
    k_seq = np.zeros((horizon, m, n))
    ff_seq = np.zeros((horizon, m))
    p_seq = np.zeros((horizon + 1, n, n))
    p_seq[horizon] = p_next
    for k in range(horizon - 1, -1, -1):
        s = r + b.T @ p_next @ b
        gain = np.linalg.solve(s, b.T @ p_next @ a)
        k_v = np.linalg.solve(s, b.T)
        drive = p_next @ (e_mat @ w_seq[k]) + h_next
        k_seq[k] = gain
        ff_seq[k] = -k_v @ drive
        acl = a - b @ gain
        h_next = acl.T @ drive
        p_next = q + a.T @ p_next @ acl
        p_next = (p_next + p_next.T) / 2
        p_seq[k] = p_next
    return k_seq, ff_seq, p_seq


def detector_rows(n_q, actuated):
    """Measured rows used to see the disturbances: the rates of the actuated coordinates.

    An input disturbance shows first in the rates it accelerates; the paper's L22 uses the
    rates of the four driven coordinates (d_r', d_l', th2', th3').
    """
    return [n_q + j for j in actuated]


def robust_detector(a, b, c, e_mat, actuated, poles=None):
    """Section 6's detector gains (L1, L2) and the disturbance estimator G_w.

    L2 solves (L2 C - I) E = 0: L2 = E_a (S C E_a)^-1 S with S selecting the rows of
    ``detector_rows`` and E_a the actuated columns of E. Then Abar = (I - L2 C) A, and
    L1 places the eigenvalues of Abar - L1 C (C = I: L1 = Abar - diag(poles), exact).
    G_w (m x p) gives w^_k = G_w (y_{k+1} - C A x~_k - C B u_k), so L2 = E G_w.
    """
    n = a.shape[0]
    m = b.shape[1]
    if c.shape != (n, n) or not np.array_equal(c, np.eye(n)):
        raise DesignError("the detector design assumes the full state is measured (C = I)")
    poles = np.full(n, DEFAULT_DETECTOR_POLE) if poles is None else np.asarray(poles, dtype=float)
    if poles.shape != (n,) or np.any(np.abs(poles) >= 1):
        raise DesignError("detector poles must be %d values inside the unit circle, got %r" % (n, poles))
    rows = detector_rows(n // 2, actuated)
    e_act = e_mat[:, list(actuated)]
    ce = (c @ e_act)[rows, :]
    cond = np.linalg.cond(ce)
    if not np.isfinite(cond) or cond > 1e12:
        raise DesignError("detector condition (L2 C - I) E = 0 is not solvable: C E restricted to the "
                          "driven rates is singular (condition number %.3g)" % cond)
    g_act = np.linalg.solve(ce, np.eye(n)[rows, :])
    g_w = np.zeros((m, n))
    g_w[list(actuated), :] = g_act
    l2 = e_mat @ g_w
    abar = (np.eye(n) - l2 @ c) @ a
    l1 = abar - np.diag(poles)
    eig = np.linalg.eigvals(abar - l1 @ c)
    return l1, l2, g_w, eig


# Multipliers tried, in order, on the wheel inputs' weight of the physical variant
# (hostsim.model.gains.robust_design).
WHEEL_WEIGHT_LADDER = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 70.0, 100.0)

# Multipliers tried, in order, on the weight of the joint angles th2, th3 (the physical variant;
# hostsim.model.gains.robust_design). The paper's Q weighs them 1 beside 1e7 on th1, so its law
# bends the joints freely to balance, and joint 3's servo is softer than gravity's pull on a
# loaded link 3 (100 g at its top: 0.2 N m/rad against 0.19 from the Medium motor's 13.7 V/rad):
# the robust set's payload (hostsim.model.kalman.ROBUST_PAYLOAD_KG) asks for a stiffer one.
JOINT_WEIGHT_LADDER = (1.0, 1e2, 1e4, 1e5, 1e6, 3e6, 1e7, 3e7)
JOINT_STATES = (3, 4)
