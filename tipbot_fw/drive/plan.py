"""The drive plan: a course's timed commands -> the wheels' reference for every tick, made before
the run.

A course (tipbot_fw.drive.course) is a list of segments (forward speed, yaw rate, duration) from the
let-go cue (tick 0); after its last one the commands are zero and the robot comes to rest. Each
change of command is not followed as a step: each channel (forward speed v, yaw rate w) goes
from the old value to the new one along a smoothstep,

    v(t) = v_old + (v_new - v_old) S((t - t_i) / T),   S(x) = 3x^2 - 2x^3 on [0, 1],

whose acceleration starts and ends at zero (no jolt to the lean), with T the shortest time that
keeps its peak acceleration (1.5 |dv| / T) and its jerk (6 |dv| / T^2) within the gains' limits
(`kalman.reference.limits`, hostsim.model.reference: from the motors' voltage budget and the lean
an acceleration needs): transition_s(). The course reader refuses a segment shorter than its
own transition, so that no two changes of one channel overlap. Distance and heading are the
exact integrals, the wheels

    d_r = s + psi H/2,   d_l = s - psi H/2     (H: the track)

and their speeds and accelerations likewise, as the core's six integers per tick (positions in
1/REF_POS_STEPS of a count, the rest in 2^-16 SI: tipbot_fw.cores.kalman).

Why before the run: on the brick's soft-float CPU a profile computed in the tick costs about
30,000 instructions, more than half the tick's budget; made with numpy before the calibration
(about 0.1 s for a minute of course), a tick only copies its 48 bytes. A stall's periods are
skipped through (KalmanCore.skip): the reference keeps to the clock, as the course's times do.
A run follows the plan through tipbot_fw.drive.pathfollow, which corrects its rows from the robot's
pose in the plane. Python 3.5, numpy 1.12.
"""
import math

import numpy as np

from tipbot_fw.drive.course import channel_limits, transition_s


def smoothstep(x, dv, T):
    """(rate change, acceleration) a change dv over T seconds has made at x = elapsed / T, x in
    [0, 1] (module docstring): dv S(x) and dv S'(x) / T."""
    return dv * x * x * (3.0 - 2.0 * x), dv / T * 6.0 * x * (1.0 - x)


def _channel(targets, starts, period_s, n, lim):
    """(position, rate, acceleration) at ticks 1..n of one channel whose command changes to
    targets[i] at starts[i] (the last target held), each change a smoothstep (module
    docstring). Each change is computed over its own ticks only (a course's cost is its length,
    not its length times its segments); the position is the rate's trapezoid sum, exact where
    the rate is constant."""
    a_max, j_max = lim
    rate = np.zeros(n + 1)          # index k: tick k (tick 0: the let-go, at rest)
    acc = np.zeros(n + 1)
    steps = np.zeros(n + 2)         # each finished change's dv, from the tick after its end
    old = 0.0
    for target, t0 in zip(targets, starts):
        dv = target - old
        old = target
        if dv == 0.0:
            continue
        T = transition_s(dv, a_max, j_max)
        k0 = min(int(math.ceil(t0 / period_s)), n + 1)
        k1 = min(int(math.floor((t0 + T) / period_s)) + 1, n + 1)
        x = (np.arange(k0, k1, dtype=np.float64) * period_s - t0) / T
        d_rate, d_acc = smoothstep(x, dv, T)
        rate[k0:k1] += d_rate
        acc[k0:k1] += d_acc
        steps[k1] += dv
    rate += np.cumsum(steps)[:n + 1]
    pos = np.zeros(n + 1)
    pos[1:] = np.cumsum(0.5 * (rate[1:] + rate[:-1]) * period_s)
    return pos[1:], rate[1:], acc[1:]


def course_plan(course, limits, track_m, period_s, ref_lsb, top):
    """The plan (bytes: kalman.REF.size, 48, per tick, the reference of tick k at (k - 1) x 48: the
    first step's; the last row, at rest where the course ends, is held) of a course
    [(speed_mps, yaw_rate_rad_s, duration_s)] for a core whose reference integers have ref_lsb
    (SI per integer) and positions within +-top."""
    starts, speeds, yaws = [], [], []
    t0 = 0.0
    for speed, yaw, duration in course:
        starts.append(t0)
        speeds.append(speed)
        yaws.append(yaw)
        t0 += duration
    starts.append(t0)               # the rest after the course
    speeds.append(0.0)
    yaws.append(0.0)
    fwd, yaw_lim = channel_limits(limits)
    end_s = t0 + max(transition_s(speeds[-2], *fwd), transition_s(yaws[-2], *yaw_lim))
    n = int(math.ceil(end_s / period_s)) + 1
    s, v, a = _channel(speeds, starts, period_s, n, fwd)
    psi, w, al = _channel(yaws, starts, period_s, n, yaw_lim)
    ints = reference_ints(s, psi, v, w, a, al, track_m, ref_lsb, top)
    ints[-1, 2:] = 0                                    # the held row: at rest
    return ints.tobytes()


def reference_ints(s, psi, v, w, a, al, track_m, ref_lsb, top):
    """The core's reference integers (k x 6, '<i8') of the forward and yaw channels' distance,
    heading, rates and accelerations (arrays of k ticks): each wheel's, in the core's units."""
    h = track_m / 2.0
    si = np.column_stack([s + psi * h, s - psi * h, v + w * h, v - w * h, a + al * h, a - al * h])
    ints = si / np.array(ref_lsb, dtype=np.float64)[None, :]
    ints[:, 0:2] = np.clip(ints[:, 0:2], -top, top)     # 5 km out: beyond the fixed-point range
    return ints.astype('<i8')


def plan_for(gains, core, course):
    """The plan of a course for a Kalman core with these gains (their limits and track)."""
    ref = gains.kalman.reference
    return course_plan(course, ref.limits, ref.track_m, gains.ts_s, core.ref_lsb, core.ref_pos_top)


def drive_problem(gains, config):
    """Why these gains and configuration cannot drive (one line), or None."""
    if config.get('estimator', 'kalman') != 'kalman':
        return 'driving needs the Kalman core (config estimator: kalman), not the paper\'s detector'
    if gains.kalman is None or gains.kalman.reference is None:
        return '{} has no drive reference (kalman.reference): gains made before driving; run make gains'.format(
            gains.path)
    return None
