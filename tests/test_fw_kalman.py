"""tipbot_fw.cores.kalman: the fixed-point core equals the readable filter and law; the filter tells the
gyro bias from the lean and follows a drifting bias; no sum of the product can overflow."""
import copy
import math

import numpy as np
import pytest

import fw_support as S
from conftest import PAPER_GAINS, PHYSICAL_GAINS
from tipbot_fw.cores import fixedpoint as fx
from tipbot_fw.cores import kalman
from tipbot_fw import loop as fw_loop
from tipbot_fw.record import logfile
from tipbot_fw.guard import plausibility
from tipbot_fw.record import replay as fw_replay
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cues import OwnerCues
from tipbot_fw.session import run_session
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.gains import load_gains
from tipbot_fw.vocabulary import ACTUATED_INPUTS
from tipbot_fw.cores.kalman import KalmanCore
from tipbot_fw.cores.kalman_design import fold, reference_step
from tipbot_fw.loop import ControlLoop
from tipbot_fw.guard.safety import DeviceFailure
from tipbot_fw import vocabulary

DEG = math.pi / 180
ACT = ACTUATED_INPUTS


def committed(name):
    return load_gains({'physical': PHYSICAL_GAINS, 'paper': PAPER_GAINS}[name])


# ------------------------------------------------------------------ the folded law
def xi_step(kal, M, xi, u, m_prev, m):
    """One tick through the folded matrix, in float: -> (u_k, xi_k)."""
    n = kal.n
    v = np.concatenate([u, xi, (m - m_prev)[:2], m])
    z = M.dot(v)
    return z[:4], z[4:4 + n]


@pytest.mark.parametrize('name', ['physical', 'paper'])
def test_folded_matrix_equals_the_filter_and_the_law(name):
    kal = committed(name).kalman
    M = fold(kal.A, kal.B, kal.C, kal.L, kal.K, kal.wheel_radius_m, kal.n - kal.n_filter)
    np.testing.assert_allclose(kal.law_M, M, rtol=0, atol=1e-9 * np.abs(M).max())   # the file's
    rng = np.random.RandomState(3)
    T = np.zeros((kal.n, 5))
    T[0, 0] = T[1, 1] = kal.wheel_radius_m
    xf = rng.normal(0, 0.05, kal.n)
    m_prev = rng.normal(0, 0.1, 5)
    m_prev[:2] += 300.0                     # the wheels far from their start: xi stays small
    xf[:2] += kal.wheel_radius_m * 300.0
    xi = xf - T.dot(m_prev)
    for _ in range(200):
        u = rng.uniform(-7, 7, 4)
        m = m_prev + rng.normal(0, 0.02, 5)
        xf, u_ref = reference_step(kal, xf, u, m)
        u_fold, xi = xi_step(kal, M, xi, u, m_prev, m)
        np.testing.assert_allclose(u_fold, u_ref, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(xi + T.dot(m), xf, rtol=1e-9, atol=1e-9)
        assert np.abs(xi[:2]).max() < 1.0   # xi_d = d - R_w phi stays small however far it rolled
        m_prev = m


def test_the_absolute_wheel_angle_drops_out_of_the_update():
    # (F - I) T + L has zero wheel columns on the filter's rows: the model does not depend on
    # where the robot stands; the integrators' rows add ts R_w phi (they integrate where it is)
    g = committed('physical')
    kal = g.kalman
    n, nf = kal.n, kal.n_filter
    assert nf == n - 2
    f = (np.eye(n) - kal.L.dot(kal.C)).dot(kal.A)
    T = np.zeros((n, 5))
    T[0, 0] = T[1, 1] = kal.wheel_radius_m
    w = (f - np.eye(n)).dot(T) + kal.L
    assert np.abs(w[:nf, :2]).max() < 1e-9 * np.abs(kal.L).max()
    np.testing.assert_allclose(w[nf:, :2], g.ts_s * kal.wheel_radius_m * np.eye(2), rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------ the fixed-point core
class Robot(object):
    """The robot's linear model (a committed gains file's, SI) in closed loop with a core, with
    1-count encoders (zero at `zeros`), an integer gyro with bias (deg/s, may drift) and noise,
    and the duties as applied inputs; or open loop through given readings."""

    def __init__(self, gains, x0, bias_dps=1.0, zeros=(5000, -7000, 40, -60), noise_dps=0.3, seed=1):
        self.A, self.B = gains.A, gains.B
        self.x = np.array(x0, dtype=float)
        self.bias_dps, self.zeros = bias_dps, zeros
        self.rw = gains.kalman.wheel_radius_m
        self.rng = np.random.RandomState(seed)
        self.noise_dps = noise_dps
        self.t = 0.0

    def read(self):
        x, k = self.x, 180 / math.pi
        phi = (x[0] / self.rw - x[2], x[1] / self.rw - x[2], x[3], x[4])
        enc = tuple(int(math.floor(p * k + 0.5)) + z for p, z in zip(phi, self.zeros))
        rate = x[7] * k + self.bias(self.t) + self.noise_dps * self.rng.normal()
        return enc, (int(round(x[2] * k)), int(math.floor(rate + 0.5)))

    def bias(self, t):
        return self.bias_dps(t) if callable(self.bias_dps) else self.bias_dps

    def apply(self, duties, battery_v, ts):
        u = np.zeros(5)
        u[ACT] = np.array(duties) * battery_v / 100.0
        self.x = self.A.dot(self.x) + self.B.dot(u)
        self.t += ts


def core_duty_unrounded(core):
    """The duties of the last product before rounding: acc / 2^E (without the rounding constant)."""
    return [(int(core.acc[i]) - (1 << (core.shift_list[i] - 1))) / 2.0 ** core.row_exp[i] for i in range(4)]


def run_core(gains, robot, seconds, config=None, bias0_dps=1.0, battery_v=8.0, on_tick=None):
    core = KalmanCore(gains, config or S.fw_config())
    core.set_gyro_bias(bias0_dps)
    core.set_battery(battery_v)
    buf = bytearray(core.rows.row_bytes)
    out = []
    for k in range(int(round(seconds / gains.ts_s))):
        enc, gyro = robot.read()
        x = robot.x.copy()
        duties, stop = (core.start if k == 0 else core.step)(enc, gyro, buf, 0)
        assert not stop
        out.append((x, core.estimate(), list(duties), enc, gyro, core_duty_unrounded(core)))
        robot.apply(duties, battery_v, gains.ts_s)
        if on_tick:
            on_tick(k, core)
    return core, out


def test_the_fixed_point_core_follows_the_readable_filter_step_by_step():
    gains = committed('physical')
    kal = gains.kalman
    robot = Robot(gains, [0, 0, 0.02, 0.01, 0, 0, 0, 0, 0, 0])
    core, out = run_core(gains, robot, 10.0, config=S.fw_config(start_pose_rad={'th1': 0.02, 'th2': 0.01}))
    # the reference, fed the same readings and the same applied duties
    rpc = 2 * math.pi / 360
    zeros = out[0][3]
    xf = np.array(core.x0)
    worst_x = worst_u = worst_z = 0.0
    nf = kal.n_filter
    for k in range(1, len(out)):
        enc, gyro = out[k][3], out[k][4]
        m = np.array([(enc[0] - zeros[0]) * rpc, (enc[1] - zeros[1]) * rpc, 0.01 + (enc[2] - zeros[2]) * rpc,
                      (enc[3] - zeros[3]) * rpc, gyro[1] * DEG])
        u_prev = np.array(out[k - 1][2]) * 8.0 / 100
        xf, u = reference_step(kal, xf, u_prev, m)
        err = np.abs(np.array(out[k][1]) - xf) / np.array(kal.state_bounds)
        worst_x, worst_z = max(worst_x, np.max(err[:nf])), max(worst_z, np.max(err[nf:]))
        worst_u = max(worst_u, np.max(np.abs(np.array(out[k][5]) - u * 100 / 8.0)))
    # states within 1e-7 of their ranges (the resolution is 2^-32 of them), the integrators,
    # which add up every tick's rounding, within half a resolution step a tick; commands within
    # 1e-3 of a duty step (0.08 mV at 8 V) before their rounding, plus what the integrators'
    # rounding moves them by (K_z times it: a few hundredths of a duty step, 2 mV)
    assert worst_x < 1e-7
    assert 0 < worst_z < 0.5 * len(out) * 2.0 ** -32
    z_volts = np.abs(kal.K[:, nf:]).sum(axis=1).max() * worst_z * kal.state_bounds[nf]
    assert worst_u < 1e-3 + z_volts * 100 / 8.0 and z_volts < 0.005
    assert max(abs(np.array(o[2])).max() for o in out) > 3      # the law did work


def test_replays_of_the_core_are_bit_exact_and_the_integers_deterministic():
    gains = committed('physical')
    a = KalmanCore(gains, S.fw_config())
    b = KalmanCore(load_gains(PHYSICAL_GAINS), S.fw_config())
    for c in (a, b):
        c.set_gyro_bias(1.5)
        c.set_battery(7.83)
    assert np.array_equal(a.M, b.M) and a.shift_list == b.shift_list
    assert a.M.dtype == np.int64


@pytest.mark.parametrize('name', ['physical', 'paper'])
@pytest.mark.parametrize('battery_v', kalman.BATTERY_RANGE_V)
def test_no_sum_of_the_product_can_overflow(name, battery_v):
    core = KalmanCore(committed(name), S.fw_config())
    core.set_gyro_bias(2.0)
    core.set_battery(battery_v)
    # every input at its bound, with the sign that adds up: computed with Python's exact integers
    m = [[int(v) for v in row] for row in core.M]
    bounds = [int(b) for b in core.v_bounds]
    worst = max(sum(abs(a) * b for a, b in zip(row, bounds)) for row in m)
    assert worst < 2 ** 63
    # and numpy's int64 product agrees with the exact one there
    rng = np.random.RandomState(4)
    for _ in range(20):
        v = [int(rng.choice([-1, 1])) * b for b in bounds]
        v[-1] = 1
        exact = [sum(a * x for a, x in zip(row, v)) for row in m]
        assert core.M.dot(np.array(v, dtype=np.int64)).tolist() == exact


def test_the_law_is_scaled_for_what_an_ev3_battery_reads():
    # the loop refuses any other reading (plausibility.check_battery) before it reaches the core
    assert kalman.BATTERY_RANGE_V == (plausibility.BATTERY_MIN_V, plausibility.BATTERY_MAX_V)
    core = KalmanCore(committed('physical'), S.fw_config())
    core.set_gyro_bias(0.0)
    with pytest.raises(ValueError, match='outside the 4.5..11.0 V'):
        core.set_battery(0.001)


def test_a_wheel_count_change_beyond_the_fixed_point_range_never_reaches_the_core():
    config = S.fw_config()
    core = KalmanCore(committed('physical'), config)
    bound = plausibility.EncoderBound(config, (360,) * 4, S.TS)
    capped = bound.with_max_step(core.max_count_step)
    assert capped.per_tick == bound.per_tick < 30            # at the period the motors' reach decides
    # a tick 0.6 s late: the motors could have turned 1500 counts, the law's integers take 1023
    bound.check((0, 0, 0, 0), (1500, 0, 0, 0), 0.6, 0, 7)
    with pytest.raises(DeviceFailure, match="1500 counts in 600.0 ms, more than the control law's fixed-point range"):
        capped.check((0, 0, 0, 0), (1500, 0, 0, 0), 0.6, 0, 7)
    # and the loop applies the core's cap itself, whatever bound it was given
    readings = iter([((0, 0, 0, 0), (0, 0))] * 3 + [((5000, 0, 0, 0), (0, 0))])
    dev = MemoryDevices(source=lambda: next(readings))
    core.set_gyro_bias(0.0)
    loop = ControlLoop(dev, core, VirtualClock(), logfile.LogBuffer(10, core.rows), S.TS, 8.0, duration_s=1.0)
    with pytest.raises(DeviceFailure, match='tick 3: the encoder of right_wheel .* moved 5000 counts'):
        loop.run()


def test_joint_limits_are_checked_on_the_counts_before_the_product():
    core = KalmanCore(committed('physical'), S.fw_config(start_pose_rad={'th2': 0.2}))
    core.set_gyro_bias(0.0)
    core.set_battery(8.0)
    buf = bytearray(core.rows.row_bytes)
    core.start((0, 0, 100, 0), (0, 0), buf, 0)
    # th2 = 0.2 + counts * pi/180 <= 1.2 rad: 57 counts is 1.1948 rad, 58 is 1.2123
    assert core.step((0, 0, 157, 0), (0, 0), buf, 0)[1] == 0
    assert core.step((0, 0, 158, 0), (0, 0), buf, 0)[1] == kalman.JOINT_LIMIT
    lo2, hi2 = core.joint_bounds[:2]
    assert (lo2, hi2) == (-80, 57)


# ------------------------------------------------------------------ bias and lean
def test_a_wrong_calibrated_bias_is_corrected_and_not_taken_for_a_lean():
    # the calibration said 0 deg/s, the gyro's bias is 1 deg/s
    gains = committed('physical')
    robot = Robot(gains, np.zeros(10), bias_dps=1.0, noise_dps=0.3)
    core, out = run_core(gains, robot, 30.0, bias0_dps=0.0)
    x = np.array([o[0] for o in out])
    xh = np.array([o[1] for o in out])
    bias = xh[:, core.nf - 1] / DEG
    assert abs(bias[-400:].mean() - 1.0) < 0.03           # found within a few percent
    assert np.abs(x[-2000:, 2]).max() < 0.005              # the robot stands upright...
    assert abs(x[-1, 0]) < 0.05                            # ...and did not roll away
    # the old signal chain integrated the biased rate: 1 deg/s is 0.52 rad of lean in 30 s


def test_a_lean_at_the_start_is_found_and_not_taken_for_a_bias():
    # released at 0.02 rad while the firmware was told 0 (the Section 8 release), bias exact
    gains = committed('physical')
    robot = Robot(gains, [0, 0, 0.02, 0, 0, 0, 0, 0, 0, 0], bias_dps=1.0, noise_dps=0.3)
    core, out = run_core(gains, robot, 30.0, bias0_dps=1.0)
    x = np.array([o[0] for o in out])
    xh = np.array([o[1] for o in out])
    err = np.abs(xh[:, 2] - x[:, 2])
    assert err[0] == pytest.approx(0.02, abs=1e-9)
    assert err[400:].max() < 0.005                         # the tilt found within 2 s
    bias_err = np.abs(xh[:, core.nf - 1] / DEG - 1.0)
    assert bias_err[-1000:].max() < 0.05                   # and the bias not left learning it


def test_a_drifting_bias_is_followed():
    # 0.01 deg/s more every second for 60 s: 0.6 deg/s in all (the design case)
    gains = committed('physical')
    robot = Robot(gains, np.zeros(10), bias_dps=lambda t: 1.0 + 0.01 * t, noise_dps=0.3)
    core, out = run_core(gains, robot, 60.0, bias0_dps=1.0)
    x = np.array([o[0] for o in out])
    xh = np.array([o[1] for o in out])
    t = np.arange(len(out)) * gains.ts_s
    lag = (1.0 + 0.01 * t) - xh[:, core.nf - 1] / DEG
    assert np.abs(lag[2000:]).max() < 0.15                 # deg/s: follows with a small lag
    assert abs(0.5 * (x[-1, 0] + x[-1, 1])) < 0.05         # m: rolled less than 5 cm
    # upright (an integrated drift would be 0.6 deg/s for a minute: 0.3 rad): the integrators
    # hold the wheels where they started, so the small lag of the bias shows as lean, not travel
    assert np.abs(x[2000:, 2]).max() < 0.01


# ------------------------------------------------------------------ integral action
def without_integral_action(gains):
    """The same gains with the integrators' feedback taken out (their columns of K_a zero)."""
    out = copy.deepcopy(gains)
    kal = out.kalman
    kal.K[:, kal.n_filter:] = 0.0
    kal.law_M = fold(kal.A, kal.B, kal.C, kal.L, kal.K, kal.wheel_radius_m, kal.n - kal.n_filter)
    return out


def test_the_integrators_take_out_an_offset_the_filter_cannot_see():
    # joint 2's zero is 0.05 rad off (the firmware is told th2 = 0.05 at the start, the link is
    # at 0): an offset no estimator can see; proportional feedback alone holds the robot off its
    # start to balance it, the integrators bring the wheels back
    gains = committed('physical')
    config = S.fw_config(start_pose_rad={'th1': 0.0, 'th2': 0.05})
    ends = {}
    for name, g in (('integral', gains), ('proportional', without_integral_action(gains))):
        robot = Robot(g, np.zeros(10), bias_dps=1.0, noise_dps=0.3)
        core, out = run_core(g, robot, 20.0, config=config)
        x = np.array([o[0] for o in out])
        ends[name] = abs(0.5 * (x[-400:, 0] + x[-400:, 1]).mean())
        assert np.abs(x[:, 2]).max() < 0.05      # balanced (link 1 leans to put the mass over the wheels)
    assert ends['proportional'] > 0.005         # m: held off its start (10.8 mm with the physical gains)
    # 4.1 mm after 20 s: joint 2's slow disturbance estimate takes part of the offset first
    assert ends['integral'] < 0.4 * ends['proportional'] and ends['integral'] < 0.005


def _wheels_held_ahead(gains, hold_m):
    """A device source: both wheels still for the calibration, then pushed hold_m ahead of their
    zero and held there (a hand, a wall)."""
    held = int(round(hold_m / (gains.kalman.wheel_radius_m * 2 * math.pi / 360)))
    reads = [0]

    def source():
        reads[0] += 1
        c = min(held, max(0, reads[0] - 50))
        return (c, c, 0, 0), (0, 0)
    return source


@pytest.mark.parametrize('battery_period_s', [1.0, 5.0])     # the wind-down's own second, whatever the battery's
def test_the_integrators_stay_within_their_authority_when_the_wheels_are_held(tmp_path, battery_period_s, monkeypatch):
    # the wheels pushed 30 cm ahead of their zero and held there (a hand, a wall): without a limit
    # the integrators would reach 2 m s in 8 s; the loop keeps them within kalman.integral.limit_m_s
    # once a second (outside the tick), the log flags it and the replay does the same to the bit.
    # The law holds the wheels at their duty limit meanwhile, which the saturation stop ends after
    # limits.max_saturated_s (tests/test_fw_loop.py), and the wheel watch (a count that stays while
    # its motor is driven hard) sooner: both off here, to see the integrators' long hold
    gains = committed('physical')
    hold_m = 0.3
    dev = MemoryDevices(source=_wheels_held_ahead(gains, hold_m))
    log = str(tmp_path / 'held.log')
    monkeypatch.setattr(fw_loop, 'SATURATED_SHARE', 2.0)
    monkeypatch.setattr(fw_loop, 'STUCK_DUTY_PCT', 101)
    code, header = run_session(dev, gains, S.fw_config(battery_period_s=battery_period_s), VirtualClock(),
                               log_path=log, duration_s=8.0,
                               say=lambda m: None, cues=OwnerCues(streams=()))
    assert code == 0
    head, rows = logfile.read_log(log)
    kal = gains.kalman
    names = [c['name'] for c in head['columns']]
    z = rows[:, names.index('xi_z_r')]
    wound = (rows[:, names.index('flags')].astype(np.int64) & vocabulary.WOUND_DOWN) != 0
    limit = kal.integral_limit_m_s
    assert wound.sum() >= 3                                  # wound down, once a second
    assert np.all(np.abs(z[np.nonzero(wound)[0] + 1]) <= limit + 1.01 * hold_m * gains.ts_s)   # from there on
    assert np.abs(z).max() < limit + 1.01 * hold_m * 1.0    # one second of growth at most beyond it
    assert np.abs(z).max() > limit                           # it did wind up: the limit acted
    replayed = fw_replay.replay(head, rows, gains)
    assert np.array_equal(replayed[:, 2:], rows[:, 2:])      # the replay winds down where the log says
    saved = KalmanCore.wind_down
    try:
        KalmanCore.wind_down = lambda self: False
        assert not np.array_equal(fw_replay.replay(head, rows, gains)[:, 2:], rows[:, 2:])   # and it mattered
    finally:
        KalmanCore.wind_down = saved


def test_wheels_held_while_driven_hard_are_a_blocked_wheel_even_without_the_saturation_stop(tmp_path, monkeypatch):
    # the same hold, the saturation stop off (a law whose integrators' anti-windup keeps a blocked
    # or dead wheel below its limit): the wheel watch (a count that stays at every chunk's end for
    # STUCK_S while its motor is driven at STUCK_DUTY_PCT or more) ends the run, exit 5
    gains = committed('physical')
    monkeypatch.setattr(fw_loop, 'SATURATED_SHARE', 2.0)
    log = str(tmp_path / 'held.log')
    code, header = run_session(MemoryDevices(source=_wheels_held_ahead(gains, 0.3)), gains, S.fw_config(), VirtualClock(), log_path=log,
                               duration_s=8.0, say=lambda m: None, cues=OwnerCues(streams=()))
    assert code == 5 and header['stop_reason'] == 'device_failure', header.get('stop_message')
    assert "wheel's encoder read" in header['stop_message']
    assert header['loop']['ticks'] * gains.ts_s < 5.0     # of the 8 s asked: once the law drives the wheels hard
