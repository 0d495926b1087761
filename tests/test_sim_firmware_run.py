"""Firmware in the loop against the linear model near the equilibrium: the whole chain.

The unmodified firmware (signal chain, detector, law, saturation, duty quantization, device
layer) on the nonlinear plant with the sensor models must follow the paper's linear
simulation from a small release (th1(0) = 0.03 rad, no saturation). Stated tolerance over
the first second, where the response is larger than the sensors' resolution (after it the
joints sit within one encoder count and quantization takes over):
  th1 within 0.006 rad (20 % of the release), th2 and th3 within one encoder count
  (2 pi / 360 = 0.0175 rad), wheel displacements within 4 mm, and the firmware's
  estimate of th1 within 0.006 rad of the plant's.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from hostsim.sim.firmware_run import run_firmware
from hostsim.sim.linear_sim import simulate_linear
from hostsim.studies.montecarlo import gains_document
from hostsim.sim.scenario import Disturbance, Push, load_scenario
from tipbot_fw.gains import gains_from_dict

COUNT_RAD = 2 * math.pi / 360
WINDOW_S = 1.0


def compare(zero_kw):
    sc = load_scenario("near_equilibrium")
    doc = gains_document(sc.gains, zero_kw)
    lin = simulate_linear(gains_from_dict(doc, sc.gains), sc)
    fw = run_firmware(sc, gains_doc=doc, sysfs=False)
    n = int(round(WINDOW_S / 0.005)) + 1
    assert len(fw.t_s) >= n, "the firmware stopped at %.2f s: %s" % (fw.t_s[-1], fw.stop_reason)
    assert np.allclose(fw.t_s[:n], lin.t_s[:n], atol=1e-9)
    assert np.max(np.abs(lin.u[:n])) < 7.6                      # no saturation in the reference
    err = np.max(np.abs(fw.x[:n] - lin.x[:n]), axis=0)
    assert err[2] < 0.006, "th1 differs by %.4f rad" % err[2]
    assert err[3] < COUNT_RAD and err[4] < COUNT_RAD, "th2/th3 differ by %.4f/%.4f rad" % (err[3], err[4])
    assert err[0] < 0.004 and err[1] < 0.004, "d differs by %.4f/%.4f m" % (err[0], err[1])
    assert np.max(np.abs(fw.xhat[:n, 2] - fw.x[:n, 2])) < 0.006
    # Not trivially close: the response itself is several times the tolerance.
    assert np.ptp(lin.x[:n, 2]) > 0.03
    return fw


def test_firmware_follows_the_linear_model_with_the_shipped_gains():
    compare(zero_kw=False)


def test_firmware_follows_the_linear_model_with_kw_zeroed():
    """K_w = 0 takes the disturbance estimate (and the firmware's filter on it) out of the
    comparison: if only the previous test fails, look there first."""
    compare(zero_kw=True)


def test_sysfs_and_memory_devices_give_the_same_run():
    sc = load_scenario("near_equilibrium")
    sc = replace(sc, duration_s=0.6, sensors=replace(sc.sensors, gyro_noise_dps=0.4, gyro_bias_dps=1.2),
                 jitter_s=0.0005, extra_delay_ticks=1, seed=5)
    doc = gains_document(sc.gains, True)
    a = run_firmware(sc, gains_doc=doc, sysfs=True)
    b = run_firmware(sc, gains_doc=doc, sysfs=False)
    assert a.exit_code == b.exit_code == 0
    assert np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u)
    assert np.array_equal(a.xhat, b.xhat)


def test_disturbance_and_push_reach_the_plant_at_their_times():
    sc = replace(load_scenario("near_equilibrium"), duration_s=0.5, x0_si=(0.0,) * 10, pushes=(Push(0.2, 0.3),),
                 disturbances=(Disturbance(0.1, 0.15, (1, -1, 0, 0.5, 0)),))
    run = run_firmware(sc, gains_doc=gains_document(sc.gains, True), sysfs=False, keep_rows=False)
    t, w, x = run.t_s, run.w, run.x
    inside = (t >= 0.1 - 1e-9) & (t < 0.15 - 1e-9)
    assert np.all(w[inside] == [1, -1, 0, 0.5, 0]) and np.all(w[~inside] == 0)
    # The sample at t = 0.2 s is read just before the push acts.
    k = int(np.searchsorted(t, 0.2 - 1e-9))
    assert abs(x[k + 1, 7] - x[k, 7]) > 0.2 and abs(x[k, 7] - x[k - 1, 7]) < 0.1


def test_a_ctrl_c_during_a_firmware_run_ends_the_host_job(monkeypatch):
    # the firmware's guard turns the signal into a planned stop of its run; the host's job
    # (make sim) must end too, not go on to its next run
    import os
    import signal
    from hostsim.sim import firmware_run
    from hostsim.sim.scenario import load_scenario
    from hostsim.world.lockstep import World
    real = World.on_sleep
    calls = []

    def on_sleep(self, t_from, t_to):
        calls.append(t_to)
        if len(calls) == 300:
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, t_from, t_to)
    monkeypatch.setattr(World, "on_sleep", on_sleep)
    with pytest.raises(KeyboardInterrupt):
        firmware_run.run_firmware(load_scenario("section8"), sysfs=False)
    assert 300 <= len(calls) < 2000       # it stopped soon after the signal, not at the run's end


def test_the_world_lets_go_where_the_sessions_own_timing_says():
    # the session records its calibration's end and its loop's start in the log's header; the
    # read-back refuses a world that let go outside them (the lock-step broken)
    import types
    from hostsim.sim.firmware_build import SimulationError
    from hostsim.sim.firmware_readback import check_timing
    from hostsim.sim.scenario import load_scenario
    run = run_firmware(load_scenario("section7"), sysfs=False, keep_rows=False)
    timing = run.header["timing"]
    assert timing["calibration_start_s"] < timing["calibration_end_s"] <= timing["loop_start_s"]
    assert timing["calibration_end_s"] == pytest.approx(1.095, abs=1e-9)      # 0.1 s settle + 1 s at 5 ms
    world = types.SimpleNamespace(released=True, t_release_s=timing["calibration_end_s"])
    check_timing(world, run.header, 0.005)
    world.t_release_s = timing["calibration_end_s"] - 0.005       # a tick early: the calibration saw it move
    with pytest.raises(SimulationError, match="let go at"):
        check_timing(world, run.header, 0.005)


@pytest.mark.parametrize("sensor", ["gyro", "right_encoder"])
def test_a_sensor_that_stops_mid_run_ends_with_the_motors_stopped(sensor):
    """A sensor whose reading stops changing 2 s after the let-go, with no error to read: the
    gyro (its UART stops, the value stays) lets the robot fall while the estimate stays upright;
    the right wheel's encoder (a loose cable) makes the law drive that wheel on and on while the
    robot rolls away upright. Neither is implausible on its own; the saturation stop ends the
    first, the wheel watch (a count that stays while its motor is driven hard) the second
    (tipbot_fw.loop; without them both ran the whole 12 s, the fallen robot's wheels at 7.4 V).
    A floor at 90 degrees, where the fallen robot lies."""
    from hostsim.sim.firmware_build import build_run
    from hostsim.sim.firmware_readback import read_back
    from hostsim.sim.firmware_run import _session
    sc = replace(load_scenario("section8_physical"), duration_s=12.0, modes=("firmware",))
    run = build_run(sc, sysfs=False)
    world, sensors = run.world, run.world.sensors
    t_fault = world.t_release_s + 2.0
    encoders, gyro, publish, held = sensors.encoders, sensors.gyro, world.publish, {}
    now = [0.0]

    def stuck_encoders(x):
        counts = encoders(x)
        if sensor == "right_encoder" and now[0] >= t_fault:
            return (held.setdefault("enc", counts[0]),) + tuple(counts[1:])
        return counts

    def stuck_gyro(x, t_s):
        return held.setdefault("gyro", gyro(x, t_s)) if sensor == "gyro" and t_s >= t_fault else gyro(x, t_s)

    def on_the_floor(t_s):
        now[0] = t_s
        x = world.plant.x
        if abs(x[2]) > math.pi / 2:
            x[2], x[7] = math.copysign(math.pi / 2, x[2]), 0.0
        publish(t_s)

    sensors.encoders, sensors.gyro, world.publish = stuck_encoders, stuck_gyro, on_the_floor
    code, header, _ = _session(run, None, sc.duration_s)
    r = read_back(run, code, header, None, None)
    if sensor == "gyro":
        assert r.exit_code == 6 and r.stop_reason == "saturated", header.get("stop_message")
        assert "_wheel" in header["stop_message"]
    else:       # the law's integrators and their anti-windup need not saturate it: the wheel watch
        assert r.exit_code == 5 and r.stop_reason == "device_failure", header.get("stop_message")
        assert "the right wheel's encoder read" in header["stop_message"]
    assert 1.0 < r.t_s[-1] - 2.0 < 9.0
