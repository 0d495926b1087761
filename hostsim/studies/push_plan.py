"""A recovery planned from a detected push on link 3: how much of the LP bound it can hold.

hostsim.studies.push_limit bounds the push on link 3 that ANY input sequence within u_max
recovers (0.250 N s on the physical model) and shows that the LP's plan, tracked with the
exact state from the push on, recovers 0.238 N s on the nonlinear plant. A firmware cannot
start at the push: it sees it in its readings one tick later at the earliest (a push between
two reads), it needs a tick or two more to tell it from noise, and meanwhile its law acts on
an estimate that has not yet seen the push. This module bounds what a plan started j ticks
after the push can still recover, on the model the brick lives with:

- **The delayed model** (delayed_model): the duties land DELAY_S into the tick, after the
  tick's reads (x+ = A x + B1 u_k + B0 u_{k-1}, u_{k-1} carried as states).
- **The first j ticks** (loop_response): the linear loop of plant, the gains' Kalman filter
  and law from a unit push right after a tick's read. Linear in the push as long as nothing
  saturates (the law asks 2-4 V in those ticks at 0.25 N s), so P t_j is the state j ticks
  after a push P.
- **The plan** (plan_from): a linear program from P s_j (t_j and the last input) maximizes P
  over inputs within u_frac u_max for HORIZON_S, the angles within the firmware's stop limits,
  ending inside the set from which the law's own inputs stay within end_frac u_max for
  HANDOVER_S (Gilbert and Tan's admissible set, truncated): the law takes over without
  saturating. The constraints are linear and hold P = 0, so the plan scaled by p / P_max is
  feasible for any push p <= P_max along the same direction (its inputs scale too).

late_bounds() gives P_max for j = 0 (a plan that starts at the push: push_limit's bound on this
model, less what the hand-over and the delay take) to LATE_TICKS, each delay of DELAYS_S;
``python -m hostsim push-limit`` prints them. The linear model is symmetric in the push's
sign: one direction is computed.
"""
import numpy as np

from hostsim.model.kalman import delayed_plant
from tipbot_fw.vocabulary import ACTUATED_INPUTS

# The duties land this long after the tick's start: the reads before them take 1.5-2.3 ms on
# the EV3 (4 tacho reads of 0.3-0.45 ms and the gyro's; ../shared/ev3-hardware.md)
DELAY_S = 0.002
HORIZON_S = 1.0
HANDOVER_S = 1.0
PLAN_INPUT_FRACTION = 0.97     # push_limit's: the rest of u_max left to the tracking feedback
END_INPUT_FRACTION = 0.8       # the law's inputs after the hand-over: a fifth of u_max to spare
ANGLES = (2, 3, 4)
LATE_TICKS = 3
DELAYS_S = (0.0, DELAY_S)


def delayed_model(ac_si, bc_act_si, ts_s, delay_s=DELAY_S):
    """(A_d, B_d): the plant with u_{k-1} as extra states, x+ = A x + B1 u_k + B0 u_{k-1}."""
    bc = np.zeros((ac_si.shape[0], 5))
    bc[:, list(ACTUATED_INPUTS)] = bc_act_si
    a, b1, b0 = delayed_plant(ac_si, bc, ts_s, delay_s)
    act = list(ACTUATED_INPUTS)
    n, m = a.shape[0], len(act)
    ad = np.zeros((n + m, n + m))
    ad[:n, :n] = a
    ad[:n, n:] = b0[:, act]
    bd = np.vstack([b1[:, act], np.eye(m)])
    return ad, bd


def loop_response(ad, bd, kal, x_push, ticks):
    """The linear loop after a unit push right after tick 0's read (plant ad, bd; kal: the gains'
    Kalman block, its filter and law): per tick j = 0..ticks, (t_j the plant's state (10), u_j
    the law's input, xh_j the filter's estimate (n), y_j the filter's model run from rest with
    the same inputs (n): xh_j - y_j is what the push did to the estimate)."""
    n = kal.n
    s = np.zeros(ad.shape[0])
    s[:10] = x_push
    xh = np.zeros(n)
    y = np.zeros(n)
    u = np.zeros(4)
    out = [(s[:10].copy(), u.copy(), xh.copy(), y.copy())]
    for _ in range(ticks):
        s = ad @ s + bd @ u
        xp = kal.A @ xh + kal.B @ u
        xh = xp + kal.L @ (kal.C[:, :10] @ s[:10] - kal.C @ xp)
        y = kal.A @ y + kal.B @ u
        u = -kal.K @ xh
        out.append((s[:10].copy(), u.copy(), xh.copy(), y.copy()))
    return out


def plan_from(solve, ad, bd, k10, s0, ts_s, u_max_v, joint_limits, horizon_s=HORIZON_S, handover_s=HANDOVER_S,
              u_frac=PLAN_INPUT_FRACTION, end_frac=END_INPUT_FRACTION):
    """The LP (module docstring) from the delayed state direction s0 (x, u_prev: 14), solved by
    solve (push_limit's LP solver: max the first variable, with its fallbacks and errors):
    -> (P_max, u (N x 4), s (N+1 x 14)) for the push P_max."""
    from scipy import sparse

    ns, m = bd.shape
    steps = int(round(horizon_s / ts_s))
    ix = 1 + m * steps
    nv = ix + ns * steps
    col_p = np.zeros((ns * steps, 1))
    col_p[:ns, 0] = -ad @ s0
    dyn = sparse.hstack([sparse.csr_matrix(col_p), -sparse.kron(sparse.identity(steps), bd),
                         sparse.identity(ns * steps) - sparse.kron(sparse.eye(steps, k=-1), ad)]).tocsr()
    # the law's inputs from s_N over the hand-over, within end_frac u_max
    kd = np.hstack([k10, np.zeros((m, ns - 10))])
    acl = ad - bd @ kd
    rows, p = [], np.eye(ns)
    for _ in range(int(round(handover_s / ts_s))):
        rows.append(kd @ p)
        p = acl @ p
    h = np.vstack(rows)
    last = np.zeros((h.shape[0], nv))
    last[:, nv - ns:] = h
    umax = u_frac * u_max_v
    box = [(None, None)] * ns
    for i, lim in zip(ANGLES, joint_limits):
        box[i] = (-lim, lim)
    res = solve(nv, [dyn], list(last) + list(-last), [end_frac * u_max_v] * (2 * h.shape[0]),
                 [(-umax, umax)] * (m * steps) + box * steps, "recover")
    pmax = float(res.x[0])
    return pmax, res.x[1:ix].reshape(steps, m), np.vstack([pmax * s0, res.x[ix:].reshape(steps, ns)])


def continuous_model(d):
    """(A_c, B_c) in SI on the actuated inputs of push_limit.load_design's model."""
    from hostsim.model.equations import state_scale_to_si

    ac, bc = d["model"].linearize()
    t = state_scale_to_si(d["model"].variant)
    return t @ ac @ np.linalg.inv(t), (t @ bc)[:, d["actuated"]]


def late_bounds(solve, d, kal, joint_limits, delays_s=DELAYS_S, late_ticks=LATE_TICKS, u_frac=1.0,
                end_frac=END_INPUT_FRACTION):
    """-> [{"variant", "delay_s", "start_tick", "recoverable_n_s"}]: the largest push a plan
    started start_tick ticks after it recovers (module docstring), the law acting before; d:
    push_limit.load_design's, kal: the same gains' Kalman block, solve: plan_from's."""
    ac, bc = continuous_model(d)
    rows = []
    for delay in delays_s:
        ad, bd = delayed_model(ac, bc, d["ts_s"], delay)
        resp = loop_response(ad, bd, kal, d["x_push"], late_ticks)
        for j in range(late_ticks + 1):
            s0 = np.concatenate([resp[j][0], resp[j - 1][1] if j else np.zeros(bd.shape[1])])
            p = plan_from(solve, ad, bd, d["K"], s0, d["ts_s"], d["u_max_v"], joint_limits, u_frac=u_frac,
                          end_frac=end_frac)[0]
            rows.append({"variant": d["variant"], "delay_s": delay, "start_tick": j, "recoverable_n_s": p})
    return rows
