"""Fits of the owner's experiments (tipbot_fw.experiments): the fall pole, a joint's lever and inertia.

Shared by the host (``python -m hostsim fit-robot``, hostsim.model.robotfit) and the brick's
pre-flight check (tipbot_fw.preflight): numpy 1.12 and Python 3.5, no scipy.

**The fall.** With the joints held the robot is one rigid body on its wheels. In the
coordinates tilt th and wheel angle relative to link 1 psi (what the wheel encoders count),
the wheel motors' torques act on psi only (a torque pair between the wheel and link 1), so the
tilt's equation is the momentum balance about the axle, free of every motor, friction and
backlash term (R_w the wheel radius, Mh the robot's lever about the axle, I_a its inertia about
the axle, A = (M + 2 m_w) R_w^2 + 2 J_w the wheels' share; hostsim.model.bodies):

    d/dt [A (psi' + th') + Mh R_w cos th (psi' + 2 th') + I_a th'] = Mh (g sin th - R_w sin th th' (psi' + th'))

Divided by Mh, with r = I_a / Mh and e = A / Mh (small: A is about 2 % of the robot's
inertia about the contact point, taken from the model), it leaves one unknown of the robot, the
ratio I_roll / Mh = r + 2 R_w + e, and the fall pole sqrt(g Mh / I_roll) follows:

    th'' (ratio - 2 R_w (1 - cos th)) = g sin th + R_w sin th th'^2 - (e + R_w cos th) psi''

``fit_fall`` simulates that from the release (at rest) and fits the measured tilt (the gyro's
own integral, its angle reading, bias removed; a little of its rate readings) by Gauss-Newton:
the ratio, the release time (the angle's whole degrees show it late), the true tilt where the
hand held it (an owner's upright is a degree or two off the start pose) and the gyro's
remaining bias error (its calibration reads whole deg/s, or steps of them). psi'' comes from a
cubic through the wheel angles: a correction (its coefficient is a tenth of the tilt's).

**A joint's swing.** Link 1 held, the joint's link (with what it carries, held straight) turns
about the joint:

    I theta'' = k_v u - c theta' + g a sin(theta_abs) - tau_c sgn(theta') - tau_0 - tau_b sgn(u) cos(theta_abs)

with the motor's k_v = Km / Ra and c = Km Ke / Ra + beta (the identified motor model: the
parameters), u the volts (duty x battery), theta_abs the link's angle from link 1 (held, near
upright: the joint angles below the link), I = b + Jm (the rotor's inertia counted; b the
link's about the joint, hostsim.model.bodies), a the lever, tau_c Coulomb friction, tau_0 a
constant (link 1 a little off vertical), tau_b the backlash's share (the encoder reads the
rotor; the link sits on one side of the gear's free play by the torque's sign, cos theta_abs
of a lever's angle off). Both sides pass the same filter F(s) = w^2/(s + w)^2 (the
state-variable filter method: s^2 F theta exactly, no differentiated counts), then linear least
squares for I, a, tau_c, tau_0, tau_b. The joint swings are done upside down (the log's ``hanging``):
theta_abs is then pi plus the joint angles, gravity's torque restoring.

**The axle swing** (joint 1). The robot upside down, its wheels held, the wheel motors (their
stators on link 1) driving it open-loop: the same equation for link 1 about the axle, I the
robot's inertia there plus the two rotors', a = a1 = M h, the wheel motors' torque on link 1
minus theirs on the wheels (two motors, each with its own k_v; c their sum), the angle from
upright pi plus link 1's turn (``axle_turn``). With no reference to take instruments from, they
come from the motion the least-squares fit's model predicts from the duties (``_simulate_swing``).

Standard errors: the regression's, inflated by the square root of the samples per
``CORRELATION_S`` (the integrated or filtered residuals are correlated over about that long).
"""
import math

import numpy as np

DEG = math.pi / 180.0
# How far apart two residuals of the integrated/filtered equations are roughly independent.
CORRELATION_S = 0.05
# The fall: the fit starts where the tilt has left the held pose by this much (the hand is off),
# and ends at FALL_END_RAD (sin th and the rigid body hold to there).
FALL_START_RAD = 1.5 * DEG
FALL_END_RAD = 0.45
# The swing's filter: above the swing's 1.2 Hz, below the 1-count steps' noise.
SWING_FILTER_HZ = 2.0
SWING_SKIP_S = 0.25     # the filter's start-up transient
# The duties' effective delay after the tick's read, searched: half a tick of zero-order hold
# plus the writes' latency (a few ms on the brick)
DELAYS_S = tuple(0.001 * i for i in range(11))


# What each fit's model leaves out, as a relative standard deviation added (in quadrature) to the
# fit's own standard error, by the host's fit (hostsim.model.robotfit) and the pre-flight check
# (tipbot_fw.preflight): measured on the realistic brick's gear play and friction over the owners'
# study's robots (docs/your-robot.md). The fall's ratio I_roll / Mh 2 % (the pole's half that);
# joint 2's lever 8 %; joint 3's 4 % (its hanging swing reads a3 -6 to 0 %, rms 3.6 %: the Medium
# motor's friction sticking at each reversal, which the Coulomb term does not describe; without
# that friction it reads within 1.4 %); the axle's 5 % (the gyro's scale, 2 %, and the battery's
# sag under the near-stalled wheel motors, of which the log has only the start's voltage); a
# swing's inertia 30 %, joint 3's 50 % (the same friction: b3 -52 to +7 %, mean -26 %).
MODEL_ERROR = {'fall_ratio': 0.02, 'lever1': 0.05, 'lever2': 0.08, 'lever3': 0.04, 'inertia': 0.30,
               'inertia3': 0.50}


class FitError(Exception):
    """An experiment log that cannot give a fit (the message says why)."""


def _column(header, rows, name):
    names = [c['name'] if isinstance(c, dict) else c for c in header['columns']]
    if name not in names:
        raise FitError('the log has no column {}'.format(name))
    return rows[:, names.index(name)]


def signals(header, rows):
    """An experiment log's readings in SI, the model's directions: t (s), psi (the wheels' mean
    angle relative to link 1, rad, from the first row), th2, th3 (joint angles, rad, the start
    pose's plus the change), tilt (link 1, rad, the start pose's th1 plus the gyro angle's change,
    its calibrated bias removed), rate (rad/s, bias removed), u2, u3 (volts on the joints),
    link1_rad (where link 1 was held in a swing: 0 upright, pi upside down)."""
    config = header['config']
    pol = config['polarity']
    cpr = header['counts_per_rot']
    sign = config['gyro_sign']
    pose = config['start_pose_rad']
    bias = header['calibration']['gyro_bias_dps']
    t = _column(header, rows, 'time_s')
    col = lambda n: _column(header, rows, n)     # noqa: E731
    k = [2 * math.pi / c for c in cpr]
    enc_r = pol['right_wheel'] * k[0] * (col('enc_r') - col('enc_r')[0])
    enc_l = pol['left_wheel'] * k[1] * (col('enc_l') - col('enc_l')[0])
    zero = header.get('zero_counts') or [rows[0, 1 + i] for i in range(4)]
    th2 = pose['th2'] + pol['joint2'] * k[2] * (col('enc_2') - zero[2])
    th3 = pose['th3'] + pol['joint3'] * k[3] * (col('enc_3') - zero[3])
    angle = sign * (col('gyro_angle') - col('gyro_angle')[0]) - bias * (t - t[0])
    tilt = pose['th1'] + angle * DEG
    rate = (sign * col('gyro_rate') - bias) * DEG
    bv = col('battery_v') / 100.0
    u2 = pol['joint2'] * col('duty_2') * bv
    u3 = pol['joint3'] * col('duty_3') * bv
    ur = pol['right_wheel'] * col('duty_r') * bv
    ul = pol['left_wheel'] * col('duty_l') * bv
    return dict(t=t, psi=0.5 * (enc_r + enc_l), th2=th2, th3=th3, tilt=tilt, rate=rate, u2=u2, u3=u3, ur=ur, ul=ul,
                ref=col('ref_rad'), link1_rad=math.pi if header.get('hanging') else 0.0)


def _inflation(t):
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return math.sqrt(max(1.0, CORRELATION_S / dt))


# Coulomb friction's regressor: the sign of the speed, from the counts over +-this many ticks
# (zero-phase: the filtered speed's sign lags the true reversals and leaks friction into the
# inertia; a 1-count window flickers)
SIGN_TICKS = 4


def _central_rate(x, t, m=SIGN_TICKS):
    """(x[k+m] - x[k-m]) / (t[k+m] - t[k-m]), the ends by the nearest window."""
    out = np.zeros(len(x))
    if len(x) > 2 * m:
        out[m:-m] = (x[2 * m:] - x[:-2 * m]) / (t[2 * m:] - t[:-2 * m])
        out[:m], out[-m:] = out[m], out[-m - 1]
    return out


def _iv(x, z, y, t):
    """Instrumental-variable least squares (z the instruments of the regressors x) -> (coefficients,
    standard errors (inflated), residual rms)."""
    a = z.T.dot(x)
    coef = np.linalg.solve(a, z.T.dot(y))
    res = y - x.dot(coef)
    s2 = float(res.dot(res)) / max(len(y) - x.shape[1], 1)
    try:
        ai = np.linalg.inv(a)
        cov = ai.dot(z.T.dot(z)).dot(ai.T) * s2
        se = np.sqrt(np.abs(np.diag(cov))) * _inflation(t)
    except np.linalg.LinAlgError:
        se = np.full(x.shape[1], np.inf)
    return coef, se, math.sqrt(s2)


def fall_window(sig):
    """(i0, i1): the rows the fall's fit uses (module docstring), or FitError."""
    tilt = sig['tilt']
    moved = np.nonzero(np.abs(tilt - tilt[0]) >= FALL_START_RAD)[0]
    if not len(moved):
        raise FitError('the robot never fell: its tilt stayed within {:.1f} deg of where it was held'.format(
            FALL_START_RAD / DEG))
    i0 = int(moved[0])
    far = np.nonzero(np.abs(tilt[i0:]) >= FALL_END_RAD)[0]
    i1 = i0 + int(far[0]) if len(far) else len(tilt) - 1
    if i1 - i0 < 20:
        raise FitError('too few ticks of the fall to fit: {} between the release and {:.0f} deg'.format(
            i1 - i0, FALL_END_RAD / DEG))
    return i0, i1


def simulate_fall(t, t_r, th_r, ratio, e, rw, g, psi_poly, psi_start=None):
    """The tilt at the times t of a rigid robot let go at rest at t_r from th_r (held before):
    th'' (ratio - 2 rw (1 - cos th)) = g sin th + rw sin th th'^2 - (e + rw cos th) psi'' (module
    docstring, divided by Mh; ratio = I_roll / Mh, psi'' of the polynomial psi_poly in t, or, with
    psi_start, 0 before psi_start and of psi_poly in t - psi_start after), RK4 in steps of
    FALL_STEP_S. -> (tilts, rates)."""
    dpoly = np.polyder(np.polyder(psi_poly)) if len(psi_poly) > 2 else np.zeros(1)
    if psi_start is not None:
        def psi_acc(tt):
            return float(np.polyval(dpoly, tt - psi_start)) if tt >= psi_start else 0.0
    else:
        def psi_acc(tt):
            return float(np.polyval(dpoly, tt))
    out = np.full(len(t), float(th_r))
    rates = np.zeros(len(t))
    th, w = float(th_r), 0.0
    t_now = float(t_r)

    def acc(tt, x, v):
        c = math.cos(x)
        sn = math.sin(x)
        return (g * sn + rw * sn * v * v - (e + rw * c) * psi_acc(tt)) / (ratio - 2 * rw * (1 - c))
    for k in range(len(t)):
        while t_now < t[k] - 1e-12:
            h = min(FALL_STEP_S, t[k] - t_now)
            a1 = acc(t_now, th, w)
            a2 = acc(t_now + h / 2, th + h / 2 * w, w + h / 2 * a1)
            a3 = acc(t_now + h / 2, th + h / 2 * (w + h / 2 * a1), w + h / 2 * a2)
            a4 = acc(t_now + h, th + h * (w + h / 2 * a2), w + h * a3)
            th += h * (w + h / 6 * (a1 + a2 + a3))
            w += h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            t_now += h
        out[k] = th
        rates[k] = w
    return out, rates


FALL_STEP_S = 0.005
# The rate readings' weight beside the angle's in the fall's fit: an angle reading is good to
# 0.3 deg (whole degrees), a rate reading to about 3 deg/s (steps of several deg/s, latency, scale)
RATE_WEIGHT = 0.03
# The release is searched this far back from the first tick the tilt has left the held pose: the
# hand lets go before the angle reading (in whole degrees) shows it.
RELEASE_SEARCH_S = 0.4
# Gauss-Newton steps at most (the brick runs this fit in its pre-flight check: about 20 s there)
FALL_ITERATIONS = 25


# How far before its first count the wheels' motion may have started (searched in ticks)
WHEEL_START_SEARCH_S = 0.15


def wheel_motion(t, psi):
    """The wheels' angle relative to link 1 in the fall, for the tilt's psi'' term -> (polynomial in
    t - start, start): still until ``start`` (the wheel motors' friction holds them until the
    tilt's pull on them overcomes it), then c2 (t - start)^2 + c3 (t - start)^3, least squares over
    the counts (half a count ahead once moved), start searched tick by tick up to
    WHEEL_START_SEARCH_S before the first count."""
    moved = np.nonzero(psi != psi[0])[0]
    if len(moved) < 4:
        return np.zeros(1), None
    # a count read is up to a count behind the angle it counts (whole counts): half a count ahead
    # is the angle's best guess once it has moved
    steps = np.abs(np.diff(psi))
    y = psi - psi[0]
    y = y + 0.5 * float(np.min(steps[steps > 0])) * np.sign(y)
    t_first = float(t[moved[0]])
    dt = float(np.median(np.diff(t)))
    best = None
    for k in range(int(WHEEL_START_SEARCH_S / dt) + 1):
        start = t_first - k * dt
        s = np.maximum(t - start, 0.0)
        x = np.column_stack([s ** 2, s ** 3])
        coef = np.linalg.lstsq(x, y, rcond=-1)[0]
        r = y - x.dot(coef)
        cost = float(r.dot(r))
        if best is None or cost < best[0]:
            best = (cost, np.array([coef[1], coef[0], 0.0, 0.0]), start)
    return best[1], best[2]


def fit_fall(sig, rw_m, g_m_s2, a_over_mh):
    """The fall's fit (module docstring) -> dict: the ratio I_roll / Mh (m), the fall pole (1/s)
    and its relative standard error, the release, the tilt there, the window, the joints' largest
    motion.

    An output-error fit (Gauss-Newton, numerical derivatives) of the measured tilt and tilt rate
    (RATE_WEIGHT) from the hold to the end of the window: the ratio, the release time, the true tilt while held (the start
    pose's is not known to a degree) and the gyro's remaining bias error (its calibration reads
    whole deg/s, or steps of them)."""
    i_moved, i1 = fall_window(sig)
    t = sig['t'][:i1 + 1]
    th_m = sig['tilt'][:i1 + 1]
    i_first = max(0, int(np.searchsorted(t, t[i_moved] - RELEASE_SEARCH_S)))
    t, th_m = t[i_first:], th_m[i_first:]
    rate_m = sig['rate'][i_first:i1 + 1]
    psi_poly, psi_start = wheel_motion(t - t[0], sig['psi'][i_first:i1 + 1])

    def model(x):
        ratio, t_r, th_r, b = math.exp(x[0]), x[1], x[2], x[3]
        th, w = simulate_fall(t - t[0], t_r, th_r, ratio, a_over_mh, rw_m, g_m_s2, psi_poly, psi_start)
        return np.concatenate([th - (th_r - th_m[0]) - b * (t - t[0]), (w - b) * RATE_WEIGHT])
    th_m = np.concatenate([th_m, rate_m * RATE_WEIGHT])

    t_move = t[i_moved - i_first] - t[0]
    x = np.array([math.log(0.35), max(0.0, t_move - 0.1), th_m[0] + math.copysign(0.02, th_m[len(t) - 1] - th_m[0]),
                  0.0])
    steps = np.array([0.01, 0.002, 0.001, 0.001])
    lam = 1e-3
    res = model(x) - th_m
    cost = float(res.dot(res))
    for _ in range(FALL_ITERATIONS):
        jac = np.empty((len(th_m), 4))
        for k in range(4):
            xp = x.copy()
            xp[k] += steps[k]
            jac[:, k] = (model(xp) - th_m - res) / steps[k]
        a = jac.T.dot(jac)
        gvec = jac.T.dot(res)
        while True:
            dx = -np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-12), gvec)
            xn = x + dx
            xn[1] = min(max(xn[1], 0.0), t_move)
            rn = model(xn) - th_m
            cn = float(rn.dot(rn))
            if cn <= cost or lam > 1e6:
                break
            lam *= 10.0
        if cn > cost:
            break
        done = cost - cn < 1e-10 * max(cost, 1e-12)
        x, res, cost, lam = xn, rn, cn, max(lam / 10.0, 1e-9)
        if done:
            break
    s2 = cost / max(len(th_m) - 4, 1)
    try:
        cov = np.linalg.inv(jac.T.dot(jac)) * s2
        se_log = math.sqrt(abs(cov[0, 0])) * _inflation(t)
    except np.linalg.LinAlgError:
        se_log = float('inf')
    ratio = math.exp(x[0])
    i0 = i_first + int(np.searchsorted(t - t[0], x[1]))
    joints = float(max(np.max(np.abs(sig['th2'][i0:i1 + 1] - sig['th2'][i0])),
                       np.max(np.abs(sig['th3'][i0:i1 + 1] - sig['th3'][i0]))))
    return {'ratio_m': ratio, 'pole_1_s': math.sqrt(g_m_s2 / ratio), 'pole_rel_se': 0.5 * se_log,
            'release_s': float(t[0] + x[1]), 'tilt_at_release_rad': float(x[2]), 'bias_error_rad_s': float(x[3]),
            'rms_rad': math.sqrt(s2), 'window_s': [float(t[0]), float(t[-1])], 'ticks': len(t),
            'joint_motion_rad': joints}


def _filter(x, t, hz):
    """(F x, s F x, s^2 F x) of F = w^2 / (s + w)^2 (two first-order lags, Tustin), from rest at x[0]."""
    w = 2 * math.pi * hz
    h = float(np.median(np.diff(t)))
    a = (2 - w * h) / (2 + w * h)
    b = w * h / (2 + w * h)
    y1 = np.empty(len(x))
    y2 = np.empty(len(x))
    y1[0] = y2[0] = x[0]
    for k in range(1, len(x)):
        y1[k] = a * y1[k - 1] + b * (x[k] + x[k - 1])
        y2[k] = a * y2[k - 1] + b * (y1[k] + y1[k - 1])
    return y2, w * (y1 - y2), w * w * (x - 2 * y1 + y2)


def fit_swing(sig, joint, k_v, c, g_m_s2, lever3=None):
    """The swing's fit of ``joint`` (2 or 3; 1: the axle swing) (module docstring) -> dict: inertia I (rotor
    included; it may come out at or below the rotor's where friction hides it: the caller drops
    it then), lever a, Coulomb friction, the constant, the backlash's share, their standard
    errors, the residual rms, the swing's amplitude.

    Joint 1 is the axle swing (the robot hanging from its held wheels, tipbot_fw.experiments):
    k_v a pair (the wheel motors'), c their sum, the wheel motors' torque on link 1 minus theirs
    on the wheels. Link 1's turn: ``axle_turn`` (the wheel encoders', corrected by the gyro for the
    hands' give), its angle from upright pi plus that; the motors' own motion (their friction's
    sign, their back-EMF) the wheel encoders'."""
    t = sig['t']
    if joint == 1:
        motion = -sig['psi']
        u = -(k_v[0] * sig['ur'] + k_v[1] * sig['ul'])
        theta = axle_turn(sig, -u)
        k_v = 1.0
        absolute = math.pi + theta
    else:
        theta = motion = sig['th%d' % joint]
        u = sig['u%d' % joint]
        # link 1 is held, upright or upside down (link1_rad): its tilt off that is a constant (tau_0
        # takes it), not the gyro's drifting integral
        absolute = sig.get('link1_rad', 0.0) + sig['th2'] + (sig['th3'] if joint == 3 else sig['th3'][0])
    if len(t) < 200:
        raise FitError('too few ticks to fit the swing: {}'.format(len(t)))
    span = float(np.max(theta) - np.min(theta))
    if span < 0.1:
        raise FitError('joint {} hardly moved ({:.3f} rad): was its link free to swing{}?'.format(
            joint, span, ' (the robot hanging from its held wheels)' if joint == 1 else ''))
    hz = SWING_FILTER_HZ
    # ticks where the count stood still over the sign's window: the motor may be stuck, its friction
    # anything up to its break-away, which no regressor describes; they are left out
    moving = np.abs(_central_rate(motion, t)) > 0.0
    keep = (t - t[0] >= SWING_SKIP_S) & moving
    f_th, sf_th, ssf_th = _filter(theta, t, hz)
    sf_motion = _filter(motion, t, hz)[1]
    regressors = np.column_stack([ssf_th, -g_m_s2 * _filter(np.sin(absolute), t, hz)[0],
                                  _filter(np.sign(_central_rate(motion, t)), t, hz)[0],
                                  _filter(np.ones(len(t)), t, hz)[0]])[keep]
    # instruments: the same regressors of the reference, which the encoder's counts do not blur (the
    # counts' steps in s^2 F theta would bias the inertia towards zero: errors in the variables)

    def instruments_of(reference):
        ref = reference + (absolute - theta)      # the link's reference angle from link 1
        f_r, sf_r, ssf_r = _filter(reference, t, hz)
        return np.column_stack([ssf_r, -g_m_s2 * _filter(np.sin(ref), t, hz)[0],
                                _filter(np.sign(sf_r), t, hz)[0], _filter(np.ones(len(t)), t, hz)[0]])[keep]
    if joint == 1:
        # driven open-loop, no reference: the motion the least-squares fit's model predicts from the
        # duties (the same equation, simulated) is the instruments' source
        coef = _iv(regressors, regressors, (k_v * _filter(u, t, hz)[0] - c * sf_motion)[keep], t[keep])[0]
        instruments = instruments_of(_simulate_swing(t, u, coef, c, g_m_s2, absolute[0] - theta[0]))
    else:
        instruments = instruments_of(sig['ref'])
    bend = 0.0
    if joint == 2 and lever3 is not None:
        # link 3 is held by a PD, not rigidly: the gravity torque of its bend, from its lever
        bend = g_m_s2 * lever3 * _filter(np.sin(absolute + sig['th3'] - sig['th3'][0]) - np.sin(absolute), t, hz)[0]
    best = None
    for delay in DELAYS_S:     # where the duties act: a tick's writes land, and hold, after its read
        u_d = np.interp(t - delay, t, u)
        y = (k_v * _filter(u_d, t, hz)[0] - c * sf_motion + bend)[keep]
        coef, se, rms = _iv(regressors, instruments, y, t[keep])
        if best is None or rms < best[2]:
            best = (coef, se, rms, delay)
    coef, se, rms, delay = best
    inertia, lever = float(coef[0]), float(coef[1])
    if not lever > 0:
        held = 'upside down' if joint == 1 or sig.get('link1_rad') else 'upright'
        raise FitError('joint {}: the swing gives a non-physical lever ({:.3g} kg m): was link 1 held {} and '
                       'the link free?'.format(joint, lever, held))
    return {'joint': joint, 'inertia_kg_m2': inertia, 'inertia_se': float(se[0]), 'lever_kg_m': lever,
            'lever_se': float(se[1]), 'coulomb_nm': float(coef[2]), 'offset_nm': float(coef[3]), 'rms_nm': rms, 'span_rad': span}


def axle_turn(sig, torque):
    """Link 1's turn in the axle swing (rad, from where it hung): the wheel encoders' (minus the
    wheels' mean angle relative to link 1) plus what the wheels themselves turned in the hands
    and tyres holding them, torque / K (torque: the wheel motors' on the wheels, N m). K comes from
    the gyro: its angle less the encoders' is torque / K, the gear play's side (the torque never
    changes sign: a constant), the motors' friction (its sign) and the gyro's drift (a line and a
    parabola in time), fitted by least squares. The encoders have no drift and twice the gyro's
    resolution (two of them); the gyro alone reads a1 with 20 % standard errors on heavy robots."""
    t = sig['t'] - sig['t'][0]
    enc = -sig['psi']
    gap = (sig['tilt'] - sig['tilt'][0]) - enc
    x = np.column_stack([torque, np.sign(_central_rate(enc, sig['t'])), np.ones(len(t)), t, t * t])
    coef = np.linalg.lstsq(x, gap, rcond=-1)[0]
    return enc + coef[0] * torque + coef[1] * x[:, 1]


def _simulate_swing(t, u, coef, c, g_m_s2, offset):
    """The swing's equation (module docstring; coef = I, a, tau_c, tau_0; u the torque of the
    volts) from rest at angle 0 (offset: the link's angle from upright there): -> the angles at t."""
    inertia, lever, coulomb, const = [float(v) for v in coef]
    inertia = max(inertia, 1e-6)
    out = np.zeros(len(t))
    x, v = 0.0, 0.0
    for k in range(1, len(t)):
        h = float(t[k] - t[k - 1]) / 5
        for _ in range(5):
            friction = coulomb if v > 0 else (-coulomb if v < 0 else 0.0)
            v += h * (float(u[k - 1]) - c * v + g_m_s2 * lever * math.sin(offset + x) - friction - const) / inertia
            x += h * v
        out[k] = x
    return out


def motor_constants(params, joint):
    """(k_v = Km/Ra, c = Km Ke/Ra + beta, Jm) of a joint's motor from a parameters dict; joint 1:
    the wheel motors' (k_v of each, c and Jm summed: the axle swing)."""
    if joint == 1:
        both = [motor_constants_of(params, r) for r in ('right_wheel', 'left_wheel')]
        return (both[0][0], both[1][0]), both[0][1] + both[1][1], both[0][2] + both[1][2]
    return motor_constants_of(params, 'joint%d' % joint)


def motor_constants_of(params, role):
    """(k_v, c, Jm) of the motor of ``role``."""
    km, ke, ra = params[role + '_km_nm_a'], params[role + '_ke_v_s'], params[role + '_ra_ohm']
    return km / ra, km * ke / ra + params[role + '_beta_nm_s'], params[role + '_jm_kg_m2']


def wheel_term(params):
    """A = (M + 2 m_w) R_w^2 + 2 J_w (hostsim.model.bodies.wheel_term, here for the brick)."""
    mass = params['m1_kg'] + params['m2_kg'] + params['m3_kg'] + 2 * params['mw_kg']
    return mass * params['rw_m'] ** 2 + 2 * params['jw_kg_m2']
