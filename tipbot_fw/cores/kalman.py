"""The default control core: steady-state Kalman filter and LQR law, in fixed point.

The law (docs/architecture.md, "Kalman filter"; designed by hostsim.model.kalman, carried by the
gains file's `kalman` block, SI): the filter's state x^ (n = 13: the 10 robot states, the two
wheels' input disturbances, the gyro bias), the reading m_k = [phi_r, phi_l, th2, th3, gyro]
(wheel encoders relative to link 1, joint encoders, gyro rate), the applied input u_{k-1}:

    x^_k = F x^_{k-1} + G_u u_{k-1} + L m_k,      F = (I - L C) A,  G_u = (I - L C) B
    u_k  = -K x^_k                                (then rounded to a duty and saturated)

The wheel angles grow without bound as the robot rolls, so the carried state is not x^ but

    xi_k = x^_k - T m_k,    T: R_w on d_r from phi_r and on d_l from phi_l (zero elsewhere)

(xi_d = d^ - R_w phi: the wheel position relative to the wheel's own encoder, a few cm at most;
every other entry of xi is that of x^). Written in xi, the update sees the wheel angles only
as their change over the tick (the absolute angle's coefficient, (F - I) T + L on those
columns, is exactly zero because the model does not depend on where the robot stands):

    xi_k = F xi_{k-1} + G_u u_{k-1} - F T dm_k + (F T + L - T) m_k
    u_k  = -K xi_k - K T m_k

One matrix holds both (the gains file's `kalman.law.M`, rows [u_k, xi_k], columns
[u_{k-1}, xi_{k-1}, dphi_r, dphi_l, m_k]). Every bounded quantity then has a small fixed-point
range, which is what lets the tick run in int64 (tipbot_fw.cores.fixedpoint): per tick

    v    = [duty_{k-1} (4) | xi_{k-1} (n) | dcount_r, dcount_l, the four counts from their
            zeros, gyro_rate (raw ints) | 1]
    acc  = M_int v                 one int64 numpy product
    v[:4+n] = acc >> shifts        the duties (rounded) and xi_k, in place

M_int folds in everything that is constant between battery readings: radians per count and
polarity of each encoder, the gyro's sign and deg -> rad, volts per duty of the applied input,
duties per volt and polarity of the commands, the start pose (the constant column), the
rounding constants. It is rebuilt when the battery reading changes
(outside the tick). The duties come out as rounded integers; saturation clips them.

Periods the loop missed (a stall: the process was not scheduled, a page came back from swap):
the H-bridges held the last duties u_k all along, so the model predicts through them,

    x^ <- A^m x^ + (A^(m-1) + ... + I) B u_k        (skip(m), before the next tick)

and the next tick's update starts from where the robot is now, not where it was m periods ago.
In xi the same (A's wheel-position columns are those of the identity: nothing depends on where
the robot stands, so T m_k passes through unchanged). A^m is composed from the powers A^(2^j)
made at construction, one matrix-vector product per set bit of m, in Python floats in a fixed
order (IEEE-754: the same bits on any machine, so a replay still matches): about 1 ms on the
brick for a stall of 60 periods, paid only after a stall.

Driving (tipbot_fw.drive.plan): the law tracks a moving reference, u = -K_a (x^ - x_ref) + u_ff. The
reference's wheel positions d_ref enter as the wheel angles do with the other sign (the same
law columns, in 1/REF_POS_STEPS of a count), its wheel speeds and accelerations r through the
gains' feedforward G (hostsim.model.reference: K_a x_ref's other entries plus u_ff, per unit of
r): six more integers in v, six more columns of M, zero in the filter's rows (the estimate is of
the robot, wherever the reference is). Standing, they are zero and the tick is the same to the bit.

Integral action (the physical gains; hostsim.model.kalman, "integral"): the EV3 has no absolute
tilt sensor, so a start a degree off upright or a gyro that reads rates unevenly leaves the
tilt estimate off for the filter's slowest mode (seconds), and a proportional law then holds
the robot centimetres off its reference. Two more carried states integrate each wheel's
position error, z_k = z_{k-1} + ts (d^_k - d_ref_k) (m s), and the law feeds them back (K_a's
last columns): any constant offset, of the estimate or of the floor, is taken out. They are
the last rows of the same product (A's row of z is ts times d's, L's ts times d's, so that z
sees d^_k of this very tick); they are not estimated (no measurement, no filter gain of their
own), their wheel-angle columns are ts R_w, not zero, and skip() holds them. The loop keeps
them within +-kalman.integral.limit_m_s, the authority the gains give them (a share of u_max),
once a second outside the tick (wind_down(), flagged in the log for the replay): a hand or a wall
holding the robot cannot wind them up. Their fixed-point range (2^15 m s) is what they can
reach in that second while the position error stays below 16 km (a wheel's count itself is
bounded at 5 km): the tick pays no check.
"""
import math
import struct

import numpy as np

from tipbot_fw.config import motor_polarity
from tipbot_fw.cores import fixedpoint as fx
from tipbot_fw.cores.core import Core
from tipbot_fw.cores.kalman_rows import FLOATS, FLOATS_AT, INPUTS, INTS_AT, REFERENCE_COLUMNS, KalmanRows
from tipbot_fw.cores.saturation import to_duties
from tipbot_fw.guard.plausibility import BATTERY_MAX_V, BATTERY_MIN_V
from tipbot_fw.vocabulary import ACTUATED_INPUTS, FLAG_BITS, STOP_FLAGS

FALL = FLAG_BITS['fall']
JOINT_LIMIT = FLAG_BITS['joint_limit']
N_U = len(ACTUATED_INPUTS)
N_IN = len(INPUTS)       # the counts' changes dcount_r, dcount_l; the counts from their zeros
                         # count_r, count_l, count_2, count_3; the gyro's raw rate
# Bounds of the integer inputs (fixed-point ranges), and who keeps each: the duties (the
# saturation); a wheel's count change in one tick (the control loop's plausibility check,
# tipbot_fw.guard.plausibility.EncoderBound with max_step = MAX_COUNT_STEP: a motor turns at most
# ~30 rad/s, 0.15 rad = 9 counts per 5 ms, and the check refuses a jump beyond the hardware's
# reach, at most this whatever the period or a late tick: more is a failed read); a wheel's count
# from its zero (2^23 counts, 23,300 turns, 5 km: more than a charge of the battery at full
# speed; the drive reference's position has the same bound, the two together the 2^24 of the
# firmware before the reference, so the row exponents are those of before); a joint's count
# from its zero (the joint limit stops the run first, checked here before the product); the
# gyro's raw int16 rate (the loop's check: +-440 deg/s).
DUTY_BOUND = 100
WHEEL_STEP_BOUND = 2 ** 10
MAX_COUNT_STEP = WHEEL_STEP_BOUND - 1
WHEEL_COUNT_BOUND = 2 ** 23
JOINT_COUNT_BOUND = 2 ** 10
GYRO_BOUND = 2 ** 15
INPUT_BOUNDS = (WHEEL_STEP_BOUND,) * 2 + (WHEEL_COUNT_BOUND,) * 2 + (JOINT_COUNT_BOUND,) * 2 + (GYRO_BOUND,)
# The drive reference (tipbot_fw.drive.plan; zero while the robot stands): the wheels' reference
# positions in 1/REF_POS_STEPS of a count from the zeros (a sub-count step: 0.1 mm/s at 5 ms is
# 1/13 of a count a tick), their speeds and accelerations in 2^-REF_RATE_EXP m/s and m/s^2.
# Bounds: the counts' own, 2 m/s and 16 m/s^2 (beyond the gains' limits, which the reference keeps).
N_REF = len(REFERENCE_COLUMNS)
REF_POS_STEPS = 256
REF_RATE_EXP = 16
REF_BOUNDS = (WHEEL_COUNT_BOUND * REF_POS_STEPS,) * 2 + (2 ** (1 + REF_RATE_EXP),) * 2 + (2 ** (4 + REF_RATE_EXP),) * 2
# Battery range the row exponents are chosen for (the duty scaling depends on it): what an EV3
# battery can read; the loop refuses any other reading before it reaches set_battery.
BATTERY_RANGE_V = (BATTERY_MIN_V, BATTERY_MAX_V)
LAW_COLUMNS = ('u_r', 'u_l', 'u_th2', 'u_th3')      # then xi_*, dphi_r, dphi_l, then m

_IN = struct.Struct('<{}q'.format(N_IN))
REF = struct.Struct('<6q')
_IN_REF = struct.Struct('<{}q{}s'.format(N_IN + 1, REF.size))    # the inputs, the constant 1, a reference row
_HEAD = struct.Struct('<7q')          # duty_r..duty_3, xi_d_r, xi_d_l, xi_th1
_DUTIES = struct.Struct('<4q')
_PAIR = struct.Struct('<2q')
pack_floats = FLOATS.pack_into     # the row's floats (kalman_rows.HEAD_FLOATS)
# A live plan's rows a stall's skip leaves: more than the ticks the loop may go without its side
# task, which makes them (tipbot_fw.loop.SIDE_WAIT_S: 10 ticks at 5 ms), so a tick always has one;
# the reference then runs that much behind the clock, which a remote's driver does not see
LIVE_KEEP_ROWS = 12
# skip(m) composes A^m from A^(2^j), j < SKIP_POWERS; a longer stall repeats the largest one
SKIP_POWERS = 7


def wheel_m_per_count(rw_m, polarity, counts_per_rot):
    """Metres a wheel's count moves its d (R_w times the signed angle of a count): the one
    expression of it, so the brick, the replay and the telemetry decoder agree to the bit."""
    return rw_m * polarity * 2.0 * math.pi / counts_per_rot


def _dot(a, b):
    """sum a_i b_i left to right (not sum(): CPython 3.12 made that one compensated)."""
    acc = 0.0
    for ai, bi in zip(a, b):
        acc += ai * bi
    return acc


def prediction_powers(a, b, count):
    """[(A^(2^j), (A^(2^j - 1) + ... + I) B) for j < count], as lists of rows of Python floats
    (a: n x n, b: n x p): predicting 2^j periods with the input held."""
    p = [[float(v) for v in row] for row in a]
    q = [[float(v) for v in row] for row in b]
    out = []
    for _ in range(count):
        out.append((p, q))
        # A^(2^(j+1)) = A^(2^j) A^(2^j); S_(j+1) B = A^(2^j) S_j B + S_j B
        qt, pt = list(zip(*q)), list(zip(*p))
        q = [[_dot(pr, qc) + q[r][c] for c, qc in enumerate(qt)] for r, pr in enumerate(p)]
        p = [[_dot(pr, pc) for pc in pt] for pr in p]
    return out


def predict_held(powers, x, u, periods):
    """x (list) predicted `periods` periods ahead with the input u (list) held, by the powers of
    prediction_powers: one product per set bit of periods below the largest power, the largest
    repeated for the rest (fixed order)."""
    top = len(powers) - 1
    steps = [j for j in range(top) if periods >> j & 1] + [top] * (periods >> top)
    for j in steps:
        p, q = powers[j]
        x = [_dot(pr, x) + _dot(qr, u) for pr, qr in zip(p, q)]
    return x


def ref_rows(data):
    """The drive reference's rows (REF.size bytes each, one bytes object a row) of a plan's bytes."""
    return [data[i:i + REF.size] for i in range(0, len(data), REF.size)]


class KalmanCore(Core):
    """Per-tick computation of the Kalman law; its whole state is in each log row.

    Construct, then set_gyro_bias() (after calibration), set_battery() before the first tick
    and whenever the reading changes (outside the ticks), start() for the first tick, step()
    for every later one. Both write the tick's memory row (tipbot_fw.cores.kalman_rows) except
    its time columns into the bytearray buf at byte offset `offset` and return (duties, stop):
    duties for Devices.write_duties, stop nonzero (FALL / JOINT_LIMIT) if the motors must be
    stopped now instead. The wheel counts' change from tick to tick must stay within
    +-MAX_COUNT_STEP (the loop's plausibility check keeps it).
    """
    estimator = 'kalman'
    max_count_step = MAX_COUNT_STEP

    @staticmethod
    def row_layout(gains, config):
        """The log row of this core for these gains (before the core is made: the log's header)."""
        return KalmanRows.for_gains(gains.kalman)

    def __init__(self, gains, config, counts_per_rot=(360, 360, 360, 360), layout=None):
        kal = gains.kalman
        self.gains = gains
        self.kal = kal
        n = self.n = kal.n
        nf = self.nf = kal.n_filter     # the filter's states; the law's integrators after them
        self.state_names = list(kal.state_names)
        self.state_units = list(kal.state_units)
        self.polarity = motor_polarity(config)
        self.counts_per_rot = tuple(counts_per_rot)
        self.rad_per_count = [self.polarity[i] * 2.0 * math.pi / self.counts_per_rot[i] for i in range(4)]
        gyro_rad = config['gyro_sign'] * math.pi / 180.0
        pose = config['start_pose_rad']
        self.pose = (float(pose['th1']), float(pose['th2']), float(pose['th3']))
        self.u_max_v = gains.u_max_v
        # fixed-point format: state exponents from the gains' bounds, row exponents for the
        # worst battery of BATTERY_RANGE_V (so they never change during a run)
        self.q = fx.state_exponents(kal.state_bounds)
        self.state_lsb = np.array([2.0 ** -e for e in self.q])
        self._wheel_lsb = (2.0 ** -self.q[0], 2.0 ** -self.q[1])
        meas = [self.rad_per_count[0], self.rad_per_count[1], self.rad_per_count[0], self.rad_per_count[1],
                self.rad_per_count[2], self.rad_per_count[3], gyro_rad]
        self.meas_factor = meas
        # the reference's columns of the law (module docstring, "Driving"), and SI per integer
        self.law = np.hstack([kal.law_M, self._reference_columns(kal)])
        # metres of wheel travel per count (the wheel's angle from its zero in x^ = xi + T m)
        self.wheel_m = [wheel_m_per_count(kal.wheel_radius_m, self.polarity[i], self.counts_per_rot[i]) for i in (0, 1)]
        self.ref_lsb = [m / REF_POS_STEPS for m in self.wheel_m] + [2.0 ** -REF_RATE_EXP] * 4
        self.plan = None        # the drive reference's rows (set_live), or None: the robot stands
        self.next_row = None
        self.live = None
        self.live_lag = 0       # periods a stall skipped that the live plan had no rows for
        self.ref_pos_top = REF_BOUNDS[0] - 1
        lo, hi = BATTERY_RANGE_V
        v_bounds = [DUTY_BOUND] * N_U + [2.0 ** fx.STATE_BITS] * n + list(INPUT_BOUNDS) + list(REF_BOUNDS)
        m_abs = np.abs(self.law) * np.array(self._col_factor(hi, abs_only=True))[None, :]
        m_abs = m_abs * np.array([100.0 / lo] * N_U + [1.0] * n)[:, None]
        # the constant column: the start pose of the joints (|pose| <= 3.2 rad)
        const_bound = np.abs(kal.law_M[:, N_U + n + 4:N_U + n + 6]).dot([3.2, 3.2])
        const_bound = const_bound * np.array([100.0 / lo] * N_U + [1.0] * n)
        rows = np.hstack([m_abs, const_bound[:, None]])
        self.row_exp = fx.row_exponents(rows.tolist(), v_bounds + [1.0])
        self.shift_list = self.row_exp[:N_U] + [self.row_exp[N_U + i] - self.q[i] for i in range(n)]
        if min(self.shift_list) < 1:
            raise ValueError('kalman law: a row has no fraction bits left (shifts {})'.format(self.shift_list))
        # buffers: v (int64, the product's input, also the row's integer block), acc. The
        # constant 1 before the reference: standing, the product stops there (the tick of before)
        self.one = one = N_U + n + N_IN
        self.n_v = one + 1 + N_REF
        self.v_bounds = v_bounds[:one] + [1.0] + v_bounds[one:]
        self.shifts = np.array(self.shift_list, dtype=np.int64)
        # the integrators' limit (wind_down), in their integer units
        self.z_limit = fx.round_half_up(kal.integral_limit_m_s, self.q[nf]) if n > nf else None
        self.v_bytes = bytearray(8 * self.n_v)
        self.v = np.frombuffer(self.v_bytes, dtype='<i8')
        self.v[one] = 1
        self.acc = np.zeros(N_U + n, dtype=np.int64)
        self.v_head = self.v[0:N_U + n]
        self.M = np.zeros((N_U + n, self.n_v), dtype=np.int64)
        self.M_stand = np.zeros((N_U + n, one + 1), dtype=np.int64)
        self.v_in = self.v[0:one + 1]
        self.dot = self.M_stand.dot
        self.rshift = np.right_shift
        self._in_off = 8 * (N_U + n)
        self._ref_off = 8 * (one + 1)
        self._row_end = INTS_AT + len(self.v_bytes)     # the row's ints: the whole of v
        self.rows = layout or self.row_layout(gains, config)
        assert self.rows.q == self.q and self.rows.has_reference
        self.rows.ref_lsb = self.ref_lsb
        lim = config['limits']
        self.limits = (lim['th1_rad'], lim['th2_rad'], lim['th3_rad'])
        t1 = fx.round_half_up(lim['th1_rad'], self.q[2])
        self.th1_bounds = (-t1, t1)
        self.joint_bounds = self._joint_bounds(lim)
        self.battery_v = None
        self.offsets = None
        self.prev = None
        self.bias0 = None
        self.x0 = None
        # the model's prediction with the input held, for skip(): A's wheel-position columns
        # are the identity's to the bit (checked), which is what lets xi pass through it
        a = np.array(kal.A, dtype=float)[:nf, :nf]
        if not (a[:, 0:2] == np.eye(nf)[:, 0:2]).all():
            raise ValueError('kalman.A: the wheel positions must not act on the model (columns d_r, d_l '
                             'of the identity)')
        self._powers = prediction_powers(a, kal.B[:nf], SKIP_POWERS)
        self._state_max = 2 ** fx.STATE_BITS

    def _joint_bounds(self, lim):
        """Counts from the zero of joints 2 and 3 within their limits (integer compares)."""
        out = []
        for i, name in ((2, 'th2_rad'), (3, 'th3_rad')):
            s = self.rad_per_count[i]
            a = (-lim[name] - self.pose[i - 1]) / s
            b = (lim[name] - self.pose[i - 1]) / s
            lo, hi = int(math.ceil(min(a, b))), int(math.floor(max(a, b)))
            if max(-lo, hi) >= JOINT_COUNT_BOUND:
                raise ValueError('limits.{} spans {} counts of joint {}: the fixed-point law allows {}'.format(
                    name, max(-lo, hi), i, JOINT_COUNT_BOUND - 1))
            out += [lo, hi]
        return tuple(out)

    @staticmethod
    def _reference_columns(kal):
        """The law's columns of the reference (SI: per rad of wheel angle, per m/s, per m/s^2):
        the reference positions act on the duties and the integrators exactly as the wheel angles
        do, with the other sign (u = -K_a (x^ - x_ref), z integrates d^ - d_ref: the same columns
        of the law); the speeds and accelerations by the gains' feedforward G. The filter's rows
        have none (their wheel-angle columns are zero): the estimate is the robot's."""
        n = kal.n
        ref = np.zeros((N_U + n, N_REF))
        counts = N_U + n + 2
        ref[:, 0:2] = -kal.law_M[:, counts:counts + 2]
        if kal.reference is not None:
            ref[:N_U, 2:] = kal.reference.G
        return ref

    def _col_factor(self, battery_v, abs_only=False):
        pol = (1, 1, 1, 1) if abs_only else self.polarity
        f = [pol[i] * battery_v / 100.0 for i in range(N_U)]
        f += [2.0 ** -e for e in self.q]
        f += [abs(x) for x in self.meas_factor] if abs_only else list(self.meas_factor)
        ref = [self.meas_factor[2] / REF_POS_STEPS, self.meas_factor[3] / REF_POS_STEPS]
        f += [abs(x) for x in ref] if abs_only else ref
        f += [2.0 ** -REF_RATE_EXP] * (N_REF - 2)
        return f

    def set_gyro_bias(self, gyro_bias_dps):
        """The calibrated bias (deg/s, the sensor's frame): the filter's initial bias state."""
        self.bias0 = float(gyro_bias_dps)

    def set_battery(self, battery_v):
        """Rebuild the integer matrix for this battery voltage (module docstring)."""
        lo, hi = BATTERY_RANGE_V
        if not lo <= battery_v <= hi:      # the callers check (plausibility.check_battery): a guard
            raise ValueError('battery reading {} V is outside the {}..{} V the control law is scaled for'.format(
                battery_v, lo, hi))
        self.battery_v = battery_v
        self.dlim = min(100, int(round(self.u_max_v * 100.0 / battery_v)))
        self.dlims = (self.dlim, -self.dlim)    # the tick's bounds (a negated int is a new object)
        n = self.n
        rowf = [self.polarity[i] * 100.0 / battery_v for i in range(N_U)] + [1.0] * n
        q = fx.quantize(self.law, self._col_factor(battery_v), rowf, self.row_exp)
        one = self.one
        self.M[:, :one] = q[:, :one]
        self.M[:, one + 1:] = q[:, one:]
        self.scale_row_f = rowf
        self.M[:, one] = self._constant_column(rowf)
        self.M_stand[:] = self.M[:, :one + 1]
        self._check_range()

    def _check_range(self):
        """No sum of the product can overflow while the inputs keep their bounds (it cannot
        by construction: this guards the construction)."""
        worst = float(np.max(fx.accumulator_bound(self.M, self.v_bounds)))
        if not worst <= 2.0 ** fx.ACC_BITS:
            raise ValueError('kalman law: the fixed-point product could reach {:.3g} > 2^{}'.format(
                worst, fx.ACC_BITS))

    def _constant_column(self, rowf):
        """Start pose of the joints (float, in a fixed order) and the rounding constants."""
        law = self.kal.law_M
        n = self.n
        j2, j3 = N_U + n + 2 + 2, N_U + n + 2 + 3
        out = []
        for i in range(N_U + n):
            c = law[i, j2] * self.pose[1] + law[i, j3] * self.pose[2]
            out.append(fx.round_half_up(c * rowf[i], self.row_exp[i]) + (1 << (self.shift_list[i] - 1)))
        return np.array(out, dtype=np.int64)

    def initial_state(self):
        """x^_0 (SI): the start pose, at rest, no disturbance, the calibrated bias."""
        th1, th2, th3 = self.pose
        rw = self.kal.wheel_radius_m
        # the bias in the filter's frame: the reading times gyro_sign, in rad/s
        return ([rw * th1, rw * th1, th1, th2, th3] + [0.0] * (self.nf - 6) + [self.meas_factor[6] * self.bias0]
                + [0.0] * (self.n - self.nf))

    def start(self, enc, gyro, buf, offset):
        """First tick: the counts are the encoder zeros; xi_0 = x^_0 (the readings are zero
        relative to themselves), u_0 = -K x^_0 rounded to duties (Python floats, fixed order)."""
        self.offsets = self.rows.offsets = (enc[0], enc[1], enc[2], enc[3])
        self.prev = (0, 0)
        x0 = [float(v) for v in self.initial_state()]
        self.x0 = x0
        k = self.kal.K
        z = [fx.round_half_up(x0[j], self.q[j]) for j in range(self.n)]
        duties = []
        for i in range(N_U):
            u = 0.0
            for j in range(self.n):
                u -= k[i, j] * x0[j]
            duties.append(int(math.floor(u * self.scale_row_f[i] + 0.5)))
        self.v[N_U:N_U + self.n] = z
        _IN.pack_into(self.v_bytes, self._in_off, 0, 0, 0, 0, 0, 0, gyro[1])
        self._check_range()
        _DUTIES.pack_into(self.v_bytes, 0, *duties)
        return self._finish(gyro[0], buf, offset)

    def step(self, enc, gyro, buf, offset):
        """Every later tick: the module docstring's product, in integers, then what _finish does,
        written out here (a call costs the tick ~650 instructions, a lookup of an attribute ~30 more
        than a local's: the brick's Python is that slow per bytecode)."""
        e0, e1, e2, e3 = enc
        gyro_angle, gyro_rate = gyro
        z0, z1, z2, z3 = self.offsets
        r0 = e0 - z0
        r1 = e1 - z1
        r2 = e2 - z2
        r3 = e3 - z3
        p0, p1 = self.prev
        self.prev = (r0, r1)
        d0 = r0 - p0        # within +-MAX_COUNT_STEP: the loop's plausibility check
        d1 = r1 - p1
        j2lo, j2hi, j3lo, j3hi = self.joint_bounds
        vb = self.v_bytes
        next_row = self.next_row
        if next_row is not None:    # driving: with this tick's reference (set_live), in one call
            _IN_REF.pack_into(vb, self._in_off, d0, d1, r0, r1, r2, r3, gyro_rate, 1, next_row())
        else:
            _IN.pack_into(vb, self._in_off, d0, d1, r0, r1, r2, r3, gyro_rate)
        if not (j2lo <= r2 <= j2hi and j3lo <= r3 <= j3hi):
            # stop before the product: beyond the limits the fixed-point range is not assured
            return self._row(JOINT_LIMIT, gyro_angle, buf, offset)
        acc = self.acc
        self.dot(self.v_in, acc)
        self.rshift(acc, self.shifts, self.v_head)
        # _finish, written out
        q0, q1, q2, q3, _, _, th1 = _HEAD.unpack_from(vb, 0)
        dlim, ndlim = self.dlims
        bits = 0
        if q0 > dlim:
            q0, bits = dlim, 1
        elif q0 < ndlim:
            q0, bits = ndlim, 1
        if q1 > dlim:
            q1, bits = dlim, bits | 2
        elif q1 < ndlim:
            q1, bits = ndlim, bits | 2
        if q2 > dlim:
            q2, bits = dlim, bits | 4
        elif q2 < ndlim:
            q2, bits = ndlim, bits | 4
        if q3 > dlim:
            q3, bits = dlim, bits | 8
        elif q3 < ndlim:
            q3, bits = ndlim, bits | 8
        if bits:
            _DUTIES.pack_into(vb, 0, q0, q1, q2, q3)
        lo, hi = self.th1_bounds
        if not lo <= th1 <= hi:
            bits |= FALL
        pack_floats(buf, offset + FLOATS_AT, self.battery_v, bits, gyro_angle)
        buf[offset + INTS_AT:offset + self._row_end] = vb
        return [q0, q1, q2, q3], bits & STOP_FLAGS

    def _finish(self, gyro_angle, buf, offset):
        """The tick's duties (v's first four, rounded) saturated, the fall check, the row: the
        first tick's (step() does the same, written out)."""
        q0, q1, q2, q3, _, _, th1 = _HEAD.unpack_from(self.v_bytes, 0)
        d0, d1, d2, d3, bits = to_duties((q0, q1, q2, q3), self.dlim)
        duties = [d0, d1, d2, d3]
        if bits:
            _DUTIES.pack_into(self.v_bytes, 0, *duties)
        lo, hi = self.th1_bounds
        if not lo <= th1 <= hi:
            bits |= FALL
        self._row(bits, gyro_angle, buf, offset)
        return duties, bits & STOP_FLAGS

    def _row(self, flags, gyro_angle, buf, offset):
        pack_floats(buf, offset + FLOATS_AT, self.battery_v, flags, gyro_angle)
        buf[offset + INTS_AT:offset + self._row_end] = self.v_bytes      # the whole of v: the row's ints
        return [0, 0, 0, 0], flags & STOP_FLAGS

    def skip(self, periods):
        """The loop missed `periods` periods after this tick, the last duties held: predict the
        carried state through them (module docstring). Outside the tick; replayed from the
        log's flags (vocabulary.SKIP_SHIFT)."""
        if periods <= 0:
            return
        if self.live is not None:       # a live plan: skip what it has, keeping LIVE_KEEP_ROWS; the
            popped = min(periods, len(self.live) - LIVE_KEEP_ROWS)     # rest its maker skips
            for _ in range(popped):         # (live_lag: a course keeps to the clock)
                self.live.popleft()
            self.live_lag += periods - popped
        n = self.nf     # the filter's states; the integrators hold through a stall
        v = self.v
        lsb = self.state_lsb
        volts = self.battery_v / 100.0
        u = [self.polarity[i] * volts * int(v[i]) for i in range(N_U)]
        x = predict_held(self._powers, [int(v[N_U + i]) * float(lsb[i]) for i in range(n)], u, periods)
        top = self._state_max
        # within the fixed-point range the product is built for (a robot that far off has
        # fallen: the next tick's fall check stops it)
        v[N_U:N_U + n] = [max(-top, min(top, fx.round_half_up(x[i], self.q[i]))) for i in range(n)]

    def wind_down(self):
        """Keep the integrators within +-kalman.integral.limit_m_s (anti-windup; module docstring,
        "Integral action"). Outside the tick: the loop once a second, the replay after the rows
        the log flags (vocabulary.WOUND_DOWN). -> True if it changed them."""
        top = self.z_limit
        if top is None:
            return False
        v = self.v
        changed = False
        for i in range(N_U + self.nf, N_U + self.n):
            z = int(v[i])
            if not -top <= z <= top:
                v[i] = top if z > 0 else -top
                changed = True
        return changed

    # -- inspection, replay
    def estimate(self):
        """x^_k after the last tick (SI floats): xi plus R_w times the wheel angles."""
        n = self.n
        xi = [int(v) * l for v, l in zip(self.v[N_U:N_U + n], self.state_lsb)]
        xi[0:2] = self.wheel_positions()
        return xi

    def wheel_positions(self):
        """(d^_r, d^_l) after the last tick (m): estimate()'s first two, without the rest (read
        with struct: a numpy element costs the brick ~2,000 instructions)."""
        xr, xl = _PAIR.unpack_from(self.v_bytes, 8 * N_U)
        cr, cl = _PAIR.unpack_from(self.v_bytes, self._in_off + 16)
        lr, ll = self._wheel_lsb
        return xr * lr + self.wheel_m[0] * cr, xl * ll + self.wheel_m[1] * cl

    def reference(self):
        """The drive reference of the last tick (SI: d_r, d_l, v_r, v_l, a_r, a_l; zeros when
        the robot stands)."""
        base = self.one + 1
        return [int(self.v[base + i]) * self.ref_lsb[i] for i in range(N_REF)]

    def _driving(self):
        self.dot = self.M.dot
        self.v_in = self.v

    def live_short(self):
        """A live plan down to the rows a stall's skip keeps (or fewer): its maker is due."""
        return self.live is not None and len(self.live) <= LIVE_KEEP_ROWS

    def set_live(self, rows):
        """Drive from a live plan: `rows` (a collections.deque of 48-byte rows, made by
        tipbot_fw.drive.pathfollow for a course, tipbot_fw.drive.remote for a remote) that the loop's slack
        keeps filled (more than LIVE_KEEP_ROWS ahead); one is taken each tick."""
        self.plan = self.live = rows
        self.next_row = rows.popleft
        self._driving()

    def set_reference(self, ints):
        """The reference's integers for the next tick, as a logged row holds them (replay)."""
        self._driving()
        REF.pack_into(self.v_bytes, self._ref_off, *ints)

    @property
    def duties(self):
        return [int(d) for d in self.v[0:N_U]]

    def angles(self, mem_row):
        """(th1, th2, th3) of a memory row (float64 view), for the stop message."""
        ints = np.ascontiguousarray(mem_row, dtype='<f8')[self.rows.ints_start:].view('<i8')
        n = self.n
        th1 = int(ints[N_U + 2]) * float(self.state_lsb[2])
        th2 = self.pose[1] + self.rad_per_count[2] * int(ints[N_U + n + 4])
        th3 = self.pose[2] + self.rad_per_count[3] * int(ints[N_U + n + 5])
        return th1, th2, th3

    def header(self):
        """What the log header needs to replay this core (docs/log-format.md)."""
        doc = self.rows.header()
        doc.update({'encoder_offsets': list(self.offsets) if self.offsets else None, 'x_hat_0': self.x0,
                    'fixed_point': {'state_exponents': self.q, 'row_exponents': self.row_exp,
                                    'shifts': self.shift_list}})
        return doc

    def restore(self, file_row, encoder_offsets):
        """State as right after the tick of a file row (a ring-buffer log's first kept row)."""
        r = self.rows
        self.offsets = self.rows.offsets = tuple(int(v) for v in encoder_offsets)
        rel = [int(file_row[r.col(c)]) - z for c, z in zip(('enc_r', 'enc_l', 'enc_2', 'enc_3'), self.offsets)]
        self.prev = (rel[0], rel[1])
        duties = [int(file_row[r.col(c)]) for c in ('duty_r', 'duty_l', 'duty_2', 'duty_3')]
        xi = [int(round(float(file_row[r.col('xi_' + s)]) * 2.0 ** e)) for s, e in zip(self.state_names, self.q)]
        _DUTIES.pack_into(self.v_bytes, 0, *duties)
        self.v[N_U:N_U + self.n] = xi
        _IN.pack_into(self.v_bytes, self._in_off, 0, 0, rel[0], rel[1], rel[2], rel[3],
                      int(file_row[r.col('gyro_rate')]))
