"""The unkind sensors: the gyro's latency, freezes, scale error, drift and steps
(hostsim.world.gyro), encoders updated every 2 ms and truncated, the battery's sag and its
2.44 mV steps (hostsim.world.sensors). Each effect is shown acting against the ideal model."""
import math

import numpy as np
import pytest

from hostsim.world.gyro import GyroModel
from hostsim.world.sensors import BatteryModel, EncoderModel, SensorModel

DT = 0.001
DEG = math.pi / 180


def feed(gyro, rate_of_t, seconds, read_every=0.005):
    """Step the gyro through rate_of_t (rad/s) for `seconds`; -> [(t, angle, rate)] read every
    read_every s."""
    out = []
    n = int(round(seconds / DT))
    every = int(round(read_every / DT))
    for k in range(1, n + 1):
        t = k * DT
        gyro.on_step(t, rate_of_t(t))
        if k % every == 0:
            out.append((t,) + gyro.read(t))
    return out


def test_gyro_with_every_effect_off_reads_like_the_ideal_sensor():
    ideal = SensorModel(0.034, gyro_bias_dps=1.3, gyro_noise_dps=0.4, rng=np.random.default_rng(7))
    model = GyroModel(DT, bias_dps=1.3, noise_dps=0.4, rng=np.random.default_rng(7))
    th1 = lambda t: 0.05 * math.sin(7 * t)
    rate = lambda t: 0.35 * math.cos(7 * t)
    for k in range(1, 501):
        t = k * DT
        model.on_step(t, rate(t))
        if k % 5 == 0:
            x = [0, 0, th1(t), 0, 0, 0, 0, rate(t), 0, 0]
            a_ideal, r_ideal = ideal.gyro(x, t)
            a, r = model.read(t)
            assert r == r_ideal and abs(a - a_ideal) <= 1


def test_gyro_latency_delays_a_rate_step():
    step = lambda t: 0.5 if t > 0.1 else 0.0           # 28.6 deg/s from t = 0.1 s
    late = feed(GyroModel(DT, latency_s=0.003), step, 0.2, read_every=DT)
    first = min(t for t, _, r in late if r > 0)
    assert first == pytest.approx(0.1 + 0.001 + 0.003, abs=1e-9)


def test_gyro_freeze_holds_the_reading_then_jumps():
    g = GyroModel(DT, freeze_s=0.042, freeze_interval_s=0.5, fx_rng=np.random.default_rng(1))
    ramp = lambda t: 2.0 * t                          # the true rate keeps growing
    reads = feed(g, ramp, 3.0, read_every=DT)
    assert len(g.freezes) >= 2
    rates = {round(t, 6): r for t, _, r in reads}
    for start, end in g.freezes:
        inside = [r for t, r in rates.items() if start < t < end]
        assert len(set(inside)) == 1 and len(inside) >= 40       # held for 42 ms
        after = rates[round(math.ceil((end + 1e-9) / DT) * DT, 6)]
        # then it jumps by what the rate did meanwhile (2 rad/s^2 x 42 ms = 4.8 deg/s)
        assert after - inside[0] >= 4


def test_gyro_scale_error_is_asymmetric():
    g = GyroModel(DT, scale_error=(-0.02, 0.0))
    turn = lambda t: (2 * math.pi if t <= 1.0 else -2 * math.pi)     # 360 deg one way, then back
    reads = feed(g, turn, 2.0)
    a1 = [a for t, a, _ in reads if abs(t - 1.0) < 1e-9][0]
    assert a1 == pytest.approx(353, abs=1)          # -2 %
    assert reads[-1][1] == pytest.approx(353 - 360, abs=1)
    assert [r for t, _, r in reads if abs(t - 0.5) < 1e-9][0] == 353
    assert [r for t, _, r in reads if abs(t - 1.5) < 1e-9][0] == -360


def test_gyro_bias_ramp_and_random_walk():
    still = lambda t: 0.0
    ramp = feed(GyroModel(DT, bias_ramp_dps_s=0.5), still, 10.0)
    assert ramp[-1][2] == 5 and ramp[-1][1] == pytest.approx(0.5 * 0.5 * 100, abs=1)
    # a walk of 1 deg/s per sqrt(s): after 25 s its spread over seeds is about 5 deg/s
    ends = [GyroModel(DT, bias_walk_dps_rt_s=1.0, fx_rng=np.random.default_rng(s)) for s in range(40)]
    for g in ends:
        for k in range(1, 25001):
            g.on_step(k * DT, 0.0)
    walk = np.array([g.bias_dps(25.0) for g in ends])
    assert 3.5 < walk.std() < 6.5
    assert GyroModel(DT).bias_dps(25.0) == 0.0


def test_gyro_rate_moves_in_steps():
    slow = lambda t: 20 * DEG * t                    # 0 to 20 deg/s in 1 s
    reads = feed(GyroModel(DT, rate_step_dps=6), slow, 1.0)
    rates = [r for _, _, r in reads]
    assert set(rates) == {0, 6, 12, 18}
    ideal = [r for _, _, r in feed(GyroModel(DT), slow, 1.0)]
    assert len(set(ideal)) == 21


def test_encoders_update_every_2_ms_and_truncate():
    enc = EncoderModel((1, 1, 1, 1), (360,) * 4, DT, update_s=0.002, truncate=True)
    seen = []
    for k in range(1, 11):
        angle = [k * 0.3 * DEG, -k * 0.3 * DEG, 0.0, 0.0]          # 0.3 count per ms
        enc.on_step(k, angle)
        seen.append(enc.read(angle))
    # latched at the even steps (k = 2, 4, ...), held over the odd ones, though the angle moves
    assert all(seen[k] == seen[k - 1] for k in range(2, 10, 2))
    assert seen[3] != seen[2]
    # truncation: 0.6 count reads 0 forward and -1 backward (rounding would read 1 and -1)
    assert seen[1][:2] == (0, -1)
    ideal = EncoderModel((1, 1, 1, 1), (360,) * 4, DT)
    assert ideal.read([0.6 * DEG, -0.6 * DEG, 0, 0])[:2] == (1, -1)


def test_encoder_update_period_must_be_whole_steps():
    with pytest.raises(ValueError, match="multiple of the plant step"):
        EncoderModel((1, 1, 1, 1), (360,) * 4, DT, update_s=0.0025)


def test_battery_sags_under_load_and_reads_in_steps():
    b = BatteryModel(8.0, r_ohm=0.2, quantum_v=0.00244, ke_v_s=(0.44,) * 4, ra_ohm=(8.3,) * 4)
    stalled = b.voltage([0.9, 0.9, 0.0, 0.0], [0.0] * 4)
    # two stalled motors at 90 %: about 0.87 A each drawn at 90 % -> about 0.28 V lost
    assert 7.6 < stalled < 7.8
    assert b.voltage([0.9, 0.9, 0, 0], [10.0, 10.0, 0, 0]) > stalled          # back-EMF: less current
    assert b.voltage([0.9, 0.9, 0, 0], [-10.0, -10.0, 0, 0]) < stalled
    assert b.voltage([0.0] * 4, [5.0] * 4) == 8.0
    r = b.reading(stalled)
    assert r <= stalled < r + 0.00244 and (r / 0.00244) == pytest.approx(round(r / 0.00244), abs=1e-6)
    stiff = BatteryModel(8.0)
    assert stiff.voltage([1.0] * 4, [0.0] * 4) == 8.0 and stiff.reading(7.123456) == 7.123456
