"""The Kalman law's design math, shared by the firmware's checks of a gains file
(tipbot_fw.gains), the host's design (hostsim.model.kalman) and the tests: the filter's model
and measurement, the law's gain, the fold of both into the one per-tick matrix the core runs
(tipbot_fw.cores.kalman, whose module docstring derives it), a tick written out, and the
spectral radius the stability checks use. numpy only (the brick checks its gains with it).
"""
import numpy as np

from tipbot_fw.vocabulary import ACTUATED_INPUTS, MEASUREMENT_NAMES

N_U = len(ACTUATED_INPUTS)
N_MEAS = len(MEASUREMENT_NAMES)


def spectral_radius(m):
    """max |eig(m)|; inf when an entry overflowed (a 1e308 in B times K), which a stability
    check then refuses like any other unstable loop."""
    if not np.all(np.isfinite(m)):
        return float('inf')
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def measurement_matrix(n, rw_m, integrators=0):
    """C_a (5 x n): [phi_r, phi_l] = d / R_w - th1 (the wheel encoders sit on link 1), th2, th3,
    gyro = th1_dot + the bias (the filter's last state; the law's integrators, after it, are
    not measured)."""
    c = np.zeros((N_MEAS, n))
    c[0, 0] = c[1, 1] = 1.0 / rw_m
    c[0, 2] = c[1, 2] = -1.0
    c[2, 3] = c[3, 4] = c[4, 7] = c[4, n - integrators - 1] = 1.0
    return c


def augmented_model(a, b_act, rw_m, dist_inputs):
    """(A_a, B_a, C_a) of the filter's model from the robot's discrete model (SI; b_act: the
    actuated inputs' columns): state [x (10), w (one per disturbed input), gyro bias], the
    disturbances entering like their inputs, disturbances and bias constant (random walks)."""
    nw = len(dist_inputs)
    n = 10 + nw + 1
    aa = np.zeros((n, n))
    aa[:10, :10] = a
    aa[:10, 10:10 + nw] = b_act[:, list(dist_inputs)]
    aa[10:, 10:] = np.eye(nw + 1)
    ba = np.zeros((n, N_U))
    ba[:10] = b_act
    return aa, ba, measurement_matrix(n, rw_m)


def fold(a, b, c, gain, k, rw_m, integrators=0):
    """The per-tick matrix of the module docstring (SI, float64) from the filter's A_a (n x n),
    B_a (n x 4), C_a (5 x n), gain L (n x 5), law K_a (4 x n) and the wheel radius of C_a; the
    last `integrators` states are the law's integrators of the wheel positions (module
    docstring, "Integral action"), which depend on where the robot stands."""
    n = a.shape[0]
    nf = n - integrators
    ikc = np.eye(n) - gain.dot(c)
    f = ikc.dot(a)
    g_u = ikc.dot(b)
    t = np.zeros((n, N_MEAS))
    t[0, 0] = t[1, 1] = rw_m
    ft = f.dot(t)
    w = ft + gain - t
    w[:nf, 0:2] = 0.0   # exactly zero by construction (module docstring); what is left is round-off
    # an integrator adds ts d_k: on the wheel angles, ts R_w (A's row of it times T, exactly)
    w[nf:, 0:2] = a[nf:, 0:2].dot(t[0:2, 0:2])
    state = np.hstack([g_u, f, -ft[:, 0:2], w])
    out = -k.dot(state)
    out[:, N_U + n + 2:] -= k.dot(t)
    return np.vstack([out, state])


def law_gain(k_si, k_w, dist_inputs, k_z=None):
    """K_a = [K_act, K_w_act (the disturbed inputs' columns), 0 (the gyro bias), K_z (the law's
    integrators', if any)]: u_act = -K_a x^ (4 x n), from the file's K (5 x 10) and K_w (5 x 5)
    in SI; dist_inputs: indices into the actuated inputs."""
    act = ACTUATED_INPUTS
    parts = [k_si[act, :], k_w[np.ix_(act, [act[i] for i in dist_inputs])], np.zeros((N_U, 1))]
    return np.hstack(parts + ([] if k_z is None else [k_z]))


def reference_step(kal, xf, u_applied, m):
    """One tick written out (x^_{k-1}, u_{k-1} volts, m_k SI) -> (x^_k, u_k unsaturated)."""
    xp = kal.A.dot(xf) + kal.B.dot(u_applied)
    xf1 = xp + kal.L.dot(m - kal.C.dot(xp))
    return xf1, -kal.K.dot(xf1)
