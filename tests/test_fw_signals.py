"""tipbot_fw.cores.signal_chain and tipbot_fw.cores.saturation: raw readings -> y, and u -> duties."""
import math

import numpy as np
import pytest

import fw_support as S
from tipbot_fw.cores.saturation import battery_constants, to_duties
from tipbot_fw.cores.signal_chain import SignalChain

TS = 0.005
DEG = math.pi / 180.0


def chain(bias=0.0, cpr=(360, 360, 360, 360), **overrides):
    return SignalChain(S.fw_config(**overrides), TS, bias, cpr)


def test_start_sets_the_encoder_zeros_and_the_start_pose():
    c = chain(start_pose_rad={'th1': 0.1, 'th2': 0.2, 'th3': -0.3})
    y = c.start((1000, -20, 7, 5), (3, 0))
    assert y == pytest.approx([0.034 * 0.1, 0.034 * 0.1, 0.1, 0.2, -0.3, 0, 0, 0, 0, 0])
    y = c.update((1000, -20, 7 + 90, 5 - 45), (3, 0))
    assert y[3] == pytest.approx(0.2 + math.pi / 2) and y[4] == pytest.approx(-0.3 - math.pi / 4)


def test_polarity_and_counts_per_revolution():
    c = chain(cpr=(720, 360, 360, 180), polarity={'right_wheel': -1, 'joint2': -1})
    c.start((0, 0, 0, 0), (0, 0))
    y = c.update((720, 360, 90, 90), (0, 0))
    assert y[0] == pytest.approx(-2 * math.pi * 0.034)      # one turn backwards
    assert y[1] == pytest.approx(2 * math.pi * 0.034)
    assert y[3] == pytest.approx(-math.pi / 2)
    assert y[4] == pytest.approx(math.pi)                   # 90 of 180 counts: half a turn


def test_th1_integrates_the_bias_corrected_rate_and_wheels_add_it():
    # link 1 tilts at 10 deg/s for 0.5 s with the wheels locked to it: the wheels roll R * th1
    c = chain(bias=2.0, gyro_bias_time_constant_s=None)
    c.start((0, 0, 0, 0), (0, 2))
    for _ in range(100):
        y = c.update((0, 0, 0, 0), (0, 12))       # raw rate = true 10 deg/s + bias 2
    assert y[2] == pytest.approx(5 * DEG, rel=1e-12)
    assert y[0] == pytest.approx(0.034 * 5 * DEG, rel=1e-12) and y[1] == y[0]
    assert y[7] == pytest.approx(10 * DEG, rel=1e-9)        # filtered rate has settled
    assert c.bias_used_dps == 2.0


def test_gyro_sign_flips_th1():
    c = chain(gyro_sign=-1)
    c.start((0, 0, 0, 0), (0, 0))
    y = c.update((0, 0, 0, 0), (0, 20))
    assert y[2] == pytest.approx(-20 * DEG * TS)


def test_filtered_differentiation_converges_to_the_slope_with_the_configured_lag():
    c = chain(filters={'encoder_rate_cutoff_hz': 10.0})
    c.start((0, 0, 0, 0), (0, 0))
    a = 1 - math.exp(-2 * math.pi * 10.0 * TS)
    slope = 2 * (2 * math.pi / 360) / TS          # joint 2 turns 2 counts per tick
    ys = [c.update((0, 0, 2 * k, 0), (0, 0))[8] for k in range(1, 201)]
    # first-order step response of the rate: 1 - (1 - a)^k
    for k in (1, 5, 20):
        assert ys[k - 1] == pytest.approx(slope * (1 - (1 - a) ** k), rel=1e-9)
    assert ys[-1] == pytest.approx(slope, rel=1e-9)


def test_bias_tracking_has_the_configured_time_constant():
    c = chain(bias=0.0, gyro_bias_time_constant_s=1.0, gyro_bias_quiet_dps=5.0)
    c.start((0, 0, 0, 0), (0, 2))
    for _ in range(199):                           # 1 s of ticks after the first
        c.update((0, 0, 0, 0), (0, 2))
    assert c.bias_dps == pytest.approx(2 * (1 - math.exp(-1)), rel=1e-3)


def test_bias_tracking_ignores_real_rotation():
    """A rotation (|rate - bias| beyond gyro_bias_quiet_dps) is motion, not bias: the tracker
    must not learn it, else th1 is high-passed and the robot drifts back to its start lean."""
    c = chain(bias=0.5, gyro_bias_time_constant_s=1.0, gyro_bias_quiet_dps=2.0)
    c.start((0, 0, 0, 0), (0, 0))
    for _ in range(200):                           # 1 s turning at 20 deg/s
        c.update((0, 0, 0, 0), (0, 20))
    b = 0.5 + (0.0 - 0.5) * (1 - math.exp(-1 / 200.0))     # only the start's quiet sample counted
    assert c.bias_dps == pytest.approx(b, rel=1e-12)
    assert c.y[2] == pytest.approx(math.radians((20 - b) * 200 * TS), rel=1e-9)
    for _ in range(200):                           # then still: the quiet samples are learned
        c.update((0, 0, 0, 0), (0, 1))
    assert 0.5 < c.bias_dps < 1.0


def test_restore_continues_exactly():
    rng = np.random.RandomState(3)
    readings = [(tuple(rng.randint(-50, 50, 4)), (int(rng.randint(-5, 5)), int(rng.randint(-30, 30))))
                for _ in range(60)]
    a = chain(bias=1.5)
    a.start(*readings[0])
    for r in readings[1:30]:
        a.update(*r)
    b = chain(bias=99.0)
    b.restore(a.offsets, a.y, a.bias_used_dps, readings[29][1][1])
    for r in readings[30:]:
        assert a.update(*r) == b.update(*r)


def reference_duty(u, u_max, battery_v):
    """The definition: saturate, then duty = round(100 u / battery), clipped to +-100."""
    u = min(max(u, -u_max), u_max)
    return min(max(round(100.0 * u / battery_v), -100), 100)


def test_duties_match_saturate_then_round_then_clip():
    rng = np.random.RandomState(4)
    for _ in range(2000):
        bv = rng.uniform(6.0, 9.0)
        q = rng.uniform(-15, 15, 4)
        scale, volts_per_duty, dlim = battery_constants(7.6, bv)
        d = to_duties(q * scale, dlim)
        assert list(d[:4]) == [reference_duty(x, 7.6, bv) for x in q]
        limited = [abs(reference_duty(x, 7.6, bv)) == dlim and abs(round(x * scale)) > dlim for x in q]
        assert d[4] == sum(bit for bit, lim in zip((1, 2, 4, 8), limited) if lim)
        assert all(type(x) is int for x in d)


def test_duty_limit_below_u_max_is_the_battery():
    assert battery_constants(7.6, 7.0)[2] == 100
    assert battery_constants(7.6, 8.0)[2] == 95
    assert to_duties((150.0, -150.0, 99.6, 0.4), 100) == (100, -100, 100, 0, 1 | 2)
