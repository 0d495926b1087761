"""Robust disturbance detector (paper Section 6) and LQR law folded into one matrix.

Per tick k+1, after reading y_{k+1} (docs/architecture.md):

    nu_k     = y_{k+1} - C A x~_k - C B u_k
    w^_k     = G_w nu_k
    x~_{k+1} = A x~_k + B u_k + L1 (y_k - C x~_k) + L2 nu_k
    w-_k     = w-_{k-1} + a (w^_k - w-_{k-1})       (low-pass, see below; a = 1: w-_k = w^_k)
    u_{k+1}  = -K x~_{k+1} - K_w w-_k               (saturated afterwards, outside the matrix)

The low-pass on the disturbance estimate (config filters.disturbance_cutoff_hz, a = 1 -
exp(-2 pi fc ts); null: a = 1, the equations of docs/architecture.md as they stand): w^ is a
one-step innovation through G_w, about the inverse of B, i.e. ~1/ts times the measurement noise;
on the robot the rates come from differentiated 1-degree encoder counts, and fed back unfiltered
w^ saturates the motors and the robot falls (the firmware-in-the-loop simulations). The
disturbances it is for change over seconds, so a ~1 Hz low-pass keeps them and drops the noise.

All of it is linear in v = [x~_k (10), w-_{k-1} (4 actuated), u_k (4 actuated), y_k (10),
y_{k+1} (10)], so one precomputed matrix gives z = [x~_{k+1} (10), w-_k (4 actuated), u_{k+1}
before saturation (4 actuated)] in one numpy call per tick. u_th1 is always 0, so its column is
dropped; row 2 of G_w is zero (checked at load), so w_th1 is dropped from the outputs. y_{k+1}
enters only through L2 and G_w, whose columns for the positions are zero in the real gains (the
disturbance acts on the rates): the columns of y_{k+1} that are exactly zero in the whole matrix
are dropped too, which changes no result (a product with 0 adds exactly 0) and saves a sixth of
the products.
"""
import numpy as np

from tipbot_fw.vocabulary import ACTUATED_INPUTS, N_INPUTS, N_STATES

N_ACT = len(ACTUATED_INPUTS)
N_FIXED = N_STATES + 2 * N_ACT + N_STATES    # x~_k, w-_{k-1}, u_k, y_k: always in v
N_OUT = N_STATES + 2 * N_ACT                 # length of z
ROUNDOFF = 1e-12
X_OUT = slice(0, N_STATES)
W_OUT = slice(N_STATES, N_STATES + N_ACT)
U_OUT = slice(N_STATES + N_ACT, N_OUT)
# blocks of v
V_X = slice(0, N_STATES)
V_W = slice(N_STATES, N_STATES + N_ACT)
V_U = slice(N_STATES + N_ACT, N_STATES + 2 * N_ACT)
V_Y0 = slice(N_STATES + 2 * N_ACT, N_FIXED)


def fold_full(g, a=1.0):
    """The 18x38 matrix on [x~_k, w-_{k-1}, u_k, y_k, y_{k+1}] of the module docstring, for SI
    gains g and the disturbance low-pass coefficient a (1: no low-pass)."""
    A, B, C = g.A, g.B, g.C
    Ba = B[:, ACTUATED_INPUTS]
    CA = C.dot(A)
    CBa = C.dot(Ba)
    zero_w = np.zeros((N_STATES, N_ACT))
    # x~_{k+1} as a function of each block of v
    P_x = np.hstack([A - g.L1.dot(C) - g.L2.dot(CA), zero_w, Ba - g.L2.dot(CBa), g.L1, g.L2])
    # w^_k (all 5 rows), then w-_k
    P_w = np.hstack([-g.G_w.dot(CA), np.zeros((N_INPUTS, N_ACT)), -g.G_w.dot(CBa),
                     np.zeros((N_INPUTS, N_STATES)), g.G_w])
    carry = np.zeros((N_INPUTS, P_w.shape[1]))
    carry[ACTUATED_INPUTS, V_W] = np.eye(N_ACT)
    P_wbar = a * P_w + (1.0 - a) * carry
    P_u = -g.K.dot(P_x) - g.K_w.dot(P_wbar)
    return np.vstack([P_x, P_wbar[ACTUATED_INPUTS, :], P_u[ACTUATED_INPUTS, :]])


def fold(g, a=1.0):
    """-> (M, y1_used): z = M v with v = [x~_k, w-_{k-1}, u_k, y_k, y_{k+1}[y1_used]].

    Entries below ROUNDOFF times the largest of their row are set to zero: the gains file
    carries 12 significant digits, so such entries are round-off of exact design zeros (the
    detector design makes (I - L2 C) B = 0 and Abar - L1 C diagonal), not information. A
    soft-float product by zero is short, so the brick computes M v faster, and the outputs move
    by less than the file's own precision. The columns of y_{k+1} that are then zero are dropped
    (module docstring).
    """
    full = fold_full(g, a)
    full[np.abs(full) < ROUNDOFF * np.abs(full).max(axis=1, keepdims=True)] = 0.0
    y1_used = [j for j in range(N_STATES) if np.any(full[:, N_FIXED + j] != 0.0)]
    M = np.hstack([full[:, :N_FIXED], full[:, [N_FIXED + j for j in y1_used]]])
    return np.ascontiguousarray(M), y1_used


def reference_step(g, xt, u, y0, y1):
    """The equations above without the low-pass (a = 1), one at a time (full 5-vectors u, w).
    For tests and documentation. -> (x~_{k+1}, w^_k, u_{k+1} before saturation)
    """
    nu = y1 - g.C.dot(g.A).dot(xt) - g.C.dot(g.B).dot(u)
    w = g.G_w.dot(nu)
    xt1 = g.A.dot(xt) + g.B.dot(u) + g.L1.dot(y0 - g.C.dot(xt)) + g.L2.dot(nu)
    u1 = -g.K.dot(xt1) - g.K_w.dot(w)
    return xt1, w, u1
