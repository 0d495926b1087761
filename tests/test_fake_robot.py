"""Starting the firmware against the fake robot (hostsim.sim.fake_robot), as `python3 -m tipbot_fw
run` does against `python -m hostsim fake-robot`, but in lock-step: the fake's wall clock is a
virtual one that the firmware's sleeps advance in 1 ms steps, so the runs are repeatable.

What an owner meets first: the robot starts on the first try with a drifting gyro however long
the fake (the gyro) has been on, a robot that moved during the calibration is refused, and a
run never starts with the robot lying on the floor.
"""
import dataclasses

import pytest

from hostsim.sim.fake_robot import RealTimeRobot
from hostsim.sim.scenario import Push, load_scenario
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.io.ev3dev import Ev3Devices
from tipbot_fw.gains import load_gains
from tipbot_fw.session import run_session
from conftest import PHYSICAL_GAINS

STEP_S = 0.001


def fake_robot(tmp_path, bias_dps, **changes):
    sc = load_scenario("section8_physical")   # gyro bias and noise, released near upright
    sc = dataclasses.replace(sc, sensors=dataclasses.replace(sc.sensors, gyro_bias_dps=bias_dps), **changes)
    return RealTimeRobot(sc, str(tmp_path / "sysfs"))


def firmware_run(robot, t_start_s, duration_s=0.3, hands=None):
    """One firmware run (the device layer on the fake's files, then a session) started
    t_start_s after the fake; hands(t, robot), t from the firmware's start, may move the held
    robot. -> (exit code, log header)."""
    robot.step(t_start_s)

    def on_sleep(t_from, t_to):
        t = t_from
        while True:
            t = min(t + STEP_S, t_to)
            if hands is not None:
                hands(t, robot)
            robot.step(t_start_s + t)
            if t >= t_to:
                return

    gains = load_gains(PHYSICAL_GAINS)
    devices = Ev3Devices(robot.config, sysfs_root=robot.fake.sysfs_root)   # run-direct, GYRO-G&A
    try:
        return run_session(devices, gains, robot.config, VirtualClock(on_sleep=on_sleep),
                           duration_s=duration_s, say=lambda m: None)
    finally:
        devices.close()
        robot.step(robot.t_s + STEP_S)      # the fake sees the motors stop


@pytest.mark.parametrize("bias_dps, running_s", [(3.0, 0.0), (-3.0, 41.3), (1.5, 600.0), (-0.7, 3600.0)])
def test_a_drifting_gyro_starts_on_the_first_try_however_long_the_fake_has_run(tmp_path, bias_dps, running_s):
    robot = fake_robot(tmp_path, bias_dps)
    try:
        code, header = firmware_run(robot, running_s)
    finally:
        robot.close()
    assert code == 0, header["stop_message"]
    cal = header["calibration"]
    assert abs(cal["gyro_bias_dps"] - bias_dps) < 0.5
    assert abs(cal["unexplained_angle_deg"]) < 1.5


def lean(t0, seconds, rate_rad_s):
    """The owner's hands tilt the held robot at rate_rad_s for `seconds` from t0."""
    def hands(t, robot):
        if t0 <= t < t0 + seconds:
            robot.plant.x[2] = robot.x0[2] + rate_rad_s * (t - t0)
            robot.plant.x[7] = rate_rad_s
        elif t >= t0 + seconds:
            robot.plant.x[7] = 0.0
    return hands


@pytest.mark.parametrize("hands, message", [
    (lean(0.5, 0.1, 1.0), "gyro rate varied by"),                              # 6 degrees in a jolt
    (lean(0.0, 2.0, 0.15), "during calibration (gyro_calibration.max_bias_dps is 5)"),   # 8.6 deg/s, steadily
])
def test_a_robot_moved_during_the_calibration_is_refused(tmp_path, hands, message):
    robot = fake_robot(tmp_path, 1.0)
    try:
        code, header = firmware_run(robot, 12.0, hands=hands)
    finally:
        robot.close()
    assert code == 4 and header["stop_reason"] == "calibration"
    assert message in header["stop_message"]


def test_a_run_never_starts_with_the_robot_lying_on_the_floor(tmp_path):
    # the first run lets the robot fall (a kick beyond what the controller can take) and stops
    # on its fall limit; the next run finds the robot picked up and held at the start pose
    robot = fake_robot(tmp_path, 0.5, pushes=(Push(t_s=0.05, th1_dot_rad_s=6.0),))
    try:
        code, header = firmware_run(robot, 1.0, duration_s=3.0)
        assert code == 6 and header["stop_reason"] == "fall"
        for t in range(50):                       # the fake goes on: the robot lies on the floor
            robot.step(robot.t_s + 0.02)
        assert robot.fallen
        robot.sc = dataclasses.replace(robot.sc, pushes=())
        code, header = firmware_run(robot, robot.t_s + 0.5, duration_s=1.0)
        assert code == 0, header["stop_message"]
        assert not robot.fallen and abs(robot.plant.x_si[2]) < 0.1
    finally:
        robot.close()
    assert len(robot.events) == 3, robot.events
    assert "picked up from the floor and held at the start pose" in robot.events[1]
