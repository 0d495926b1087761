"""The drive reference's feedforward and limits, from the linear model (issue 21).

Driving is tracking: the law holds the robot on a moving reference instead of its start,

    u = -K_a (x^ - x_ref) + u_ff,

where the reference moves the wheels (each one's position, speed and acceleration: forward
speed plus or minus the yaw rate times half the track) and the rest of x_ref and u_ff are what
the model needs to move them so: link 1 leans as the acceleration needs, the joints stay
straight (th2 = th3 = 0), the motors give the back-EMF and friction of the speed and the torque
of the acceleration. Both are linear in r = [v_r, v_l, a_r, a_l], from the continuous model's
acceleration rows (five equations, unknowns th1 and the four inputs):

    A[q'', th1] th1 + B[q''] u = [a_r, a_l, 0, 0, 0] - A[q'', d_r', d_l'] [v_r, v_l]

so the law's extra term K_a x_ref + u_ff = G r is one 4 x 4 matrix, which the gains file
carries (`kalman.reference.G`); the wheel positions' share of x_ref (K_a's d columns times the
reference positions) the firmware takes from the law's own wheel-count columns.

The limits keep the feedforward inside a share of u_max, so that the law keeps the rest to
balance (docs/course-format.md):

- speed and yaw rate: the steady feedforward at the top forward speed (or yaw rate, turning in
  place) at most SPEED_SHARE of u_max;
- accelerations: their feedforward at most ACCEL_SHARE of u_max, and link 1's lean for them at
  most LEAN_MAX_RAD;
- jerk: each acceleration built up in RAMP_S, about two time constants of the upright robot's
  unstable pole (~10/s), so that the lean the acceleration needs can be taken while it grows.
"""
import math

import numpy as np

# Shares of u_max the feedforward may take at the limits (the rest: balancing and pushes).
SPEED_SHARE = 0.4
ACCEL_SHARE = 0.2
LEAN_MAX_RAD = 0.08
RAMP_S = 0.2
# Beyond these the reference is not the limit any more but the robot's wheels' grip and the
# owner's room: caps that no design exceeds.
SPEED_CAP_MPS = 0.5
ACCEL_CAP_MPS2 = 1.0
CLEAN_BELOW = 1e-9
COLUMNS = ("v_r", "v_l", "a_r", "a_l")
UNITS = ("m/s", "m/s", "m/s^2", "m/s^2")


def quasi_steady(ac_si, bc_act_si):
    """(X (10 x 4), U (4 x 4)): the state reference and the inputs per unit of each of
    v_r, v_l, a_r, a_l (module docstring). ac_si: 10 x 10, bc_act_si: 10 x 4 (the actuated
    inputs' columns), SI, state [d_r, d_l, th1, th2, th3, rates]."""
    rows = slice(5, 10)
    m = np.column_stack([ac_si[rows, 2], bc_act_si[rows, :]])
    x = np.zeros((10, 4))
    u = np.zeros((4, 4))
    for j in range(4):
        rhs = np.zeros(5)
        xr = np.zeros(10)
        if j < 2:
            xr[5 + j] = 1.0
        else:
            rhs[j - 2] = 1.0
        z = np.linalg.solve(m, rhs - ac_si[rows, :] @ xr)
        xr[2] = z[0]
        x[:, j] = xr
        u[:, j] = z[1:]
    return x, u


def feedforward(ac_si, bc_act_si, k_a):
    """(G (4 x 4), U (4 x 4), lean (4)): the law's extra term K_a x_ref + u_ff = G r, the inputs
    u_ff = U r the motion itself takes (what the motors give while the robot tracks it) and
    link 1's lean th1 per unit of r."""
    x, u = quasi_steady(ac_si, bc_act_si)
    return k_a[:, :10] @ x + u, u, x[2, :]


def limits(u, lean, u_max_v, track_m):
    """The command limits of the module docstring, from the inputs U and the lean per unit of r."""
    g = u
    half = track_m / 2.0
    tiny = 1e-9             # a model without a term (no friction, no lean) is capped below
    forward_v = max(np.abs(g[:, 0] + g[:, 1]).max(), tiny)      # both wheels at +1 m/s
    turn_v = max(np.abs(g[:, 0] - g[:, 1]).max() * half, tiny)  # +-half track m/s per rad/s
    forward_a = max(np.abs(g[:, 2] + g[:, 3]).max(), tiny)
    turn_a = max(np.abs(g[:, 2] - g[:, 3]).max() * half, tiny)
    lean_a = max(abs(lean[2] + lean[3]), tiny)
    speed = min(SPEED_SHARE * u_max_v / forward_v, SPEED_CAP_MPS)
    yaw_rate = SPEED_SHARE * u_max_v / turn_v
    yaw_rate = min(yaw_rate, SPEED_CAP_MPS / half)
    accel = min(ACCEL_SHARE * u_max_v / forward_a, LEAN_MAX_RAD / lean_a, ACCEL_CAP_MPS2)
    yaw_accel = min(ACCEL_SHARE * u_max_v / turn_a, accel / half)     # a wheel: at most accel
    return {
        "speed_mps": speed, "accel_mps2": accel, "jerk_mps3": accel / RAMP_S,
        "yaw_rate_dps": math.degrees(yaw_rate), "yaw_accel_dps2": math.degrees(yaw_accel),
        "yaw_jerk_dps3": math.degrees(yaw_accel) / RAMP_S,
    }


WHY = ("u = -K_a (x^ - x_ref) + u_ff = -K_a x^ + (K_a's wheel-position columns) d_ref + G r, "
       "r = [v_r, v_l, a_r, a_l]: x_ref and u_ff the linear model's quasi-steady motion (link 1 "
       "leaning, joints straight); limits: feedforward at the top speed or yaw rate <= %g u_max, "
       "of the accelerations <= %g u_max and lean <= %g rad, accelerations built in %g s "
       "(hostsim.model.reference)" % (SPEED_SHARE, ACCEL_SHARE, LEAN_MAX_RAD, RAMP_S))


def reference_block(ac_si, bc_act_si, k_a, u_max_v, track_m):
    """The gains file's `kalman.reference` block."""
    g, u, lean = feedforward(ac_si, bc_act_si, k_a)
    # round-off (1e-16 V where the model has no coupling) would differ from one LAPACK to another
    g, u, lean = (np.where(np.abs(m) < CLEAN_BELOW, 0.0, m) for m in (g, u, lean))
    return {"columns": list(COLUMNS), "units": list(UNITS), "G": g, "U": u, "lean_rad": lean,
            "track_m": float(track_m), "limits": limits(u, lean, u_max_v, track_m), "why": WHY}
