"""The planar path and the tracking figures of a course (hostsim.sim.tracking), and a course
driven with the firmware in the loop."""
import dataclasses
import math

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from hostsim.sim import tracking  # noqa: E402

T = np.arange(0.0, 10.0, 0.005)
H = 0.25


def test_equal_wheels_drive_straight_and_opposite_ones_turn_in_place():
    p = tracking.planar_path(T, 0.1 * T, 0.1 * T, H)
    assert p["x_m"][-1] == pytest.approx(0.1 * T[-1]) and np.abs(p["y_m"]).max() < 1e-12
    assert np.abs(p["heading_rad"]).max() == 0.0 and p["speed_mps"][5] == pytest.approx(0.1)
    q = tracking.planar_path(T, 0.05 * T, -0.05 * T, H)
    assert np.abs(q["x_m"]).max() < 1e-12 and np.abs(q["y_m"]).max() < 1e-12
    assert q["heading_rad"][-1] == pytest.approx(2 * 0.05 * T[-1] / H)


def test_a_constant_curvature_is_the_commanded_arc():
    v, w = 0.15, math.radians(30)
    p = tracking.planar_path(T, (v + w * H / 2) * T, (v - w * H / 2) * T, H)
    c = tracking.commanded_path([(v, 30.0, T[-1])], 0.0, 0.005)
    assert np.hypot(p["x_m"] - c["x_m"][:len(T)], p["y_m"] - c["y_m"][:len(T)]).max() < 1e-3
    r = np.hypot(p["x_m"], p["y_m"] - v / w)
    assert np.abs(r - v / w).max() < 1e-3          # a circle of radius v / w about (0, v / w)


def test_the_square_course_closes():
    square = [(0.2, 0.0, 5.0), (0.0, 90.0, 1.0)] * 4
    c = tracking.commanded_path(square, 0.0)
    assert math.hypot(c["x_m"][-1], c["y_m"][-1]) < 1e-9
    assert math.degrees(c["heading_rad"][-1]) % 360 == pytest.approx(0.0, abs=1e-9)
    assert c["x_m"].max() == pytest.approx(1.0) and c["y_m"].max() == pytest.approx(1.0)


def test_cross_track_distances():
    px, py = np.array([0.0, 1.0, 1.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0])   # a repeated point
    assert tracking.cross_track_m([0.5, 1.0], [0.0, 0.5], px, py) == pytest.approx([0.0, 0.0])
    assert tracking.cross_track_m([0.5], [0.1], px, py) == pytest.approx([0.1])
    assert tracking.cross_track_m([2.0], [2.0], px, py) == pytest.approx([math.sqrt(2.0)])
    assert tracking.cross_track_m([1.0], [1.0], [0.0, 0.0], [0.0, 0.0]) == pytest.approx([math.sqrt(2.0)])


def test_tracking_figures():
    c = tracking.commanded_path([(0.2, 0.0, 4.0), (0.0, 45.0, 2.0)], 1.0, end_s=8.0)
    m = tracking.tracking_metrics(c, c)
    assert m["rms_cross_track_m"] == m["final_position_error_m"] == m["final_heading_error_deg"] == 0.0
    assert (m["max_speed_mps"], m["max_yaw_rate_dps"]) == (pytest.approx(0.2), pytest.approx(45.0))
    side = dict(c, y_m=c["y_m"] + 0.02)
    assert tracking.tracking_metrics(dict(side, heading_rad=c["heading_rad"] + math.radians(370)),
                                     c)["final_heading_error_deg"] == pytest.approx(10.0)
    straight = tracking.commanded_path([(0.2, 0.0, 4.0)], 0.0)
    off = dict(straight, y_m=straight["y_m"] + 0.02)
    assert tracking.tracking_metrics(off, straight)["rms_cross_track_m"] == pytest.approx(0.02)


def test_the_stop_time_runs_from_the_stop_command_until_the_robot_is_at_rest():
    """metrics.stop_time_s: a course of 0.2 m/s for 5 s then 3 s of rest, timed from the stop
    command (5 s). A balancing robot's limit cycle around a fixed point (0.13 m/s at its peaks, at
    2-3 Hz) is rest; a creep, or coming back after an overshoot, is not."""
    from hostsim.sim.metrics import REST_WINDOW_S, stop_time_s
    t = np.arange(0.0, 8.0, 0.005)
    course = [(0.2, 0.0, 5.0), (0.0, 0.0, 3.0)]

    def travel(after):
        """0.2 m/s until 5 s, then `after(tau)` (m, from where the robot was at 5 s)."""
        return np.where(t < 5.0, 0.2 * t, 1.0 + after(np.maximum(t - 5.0, 0.0)))

    def braking(tau, time_s=0.3):      # from 0.2 m/s to rest at a constant deceleration
        tau = np.minimum(tau, time_s)
        return 0.2 * tau - 0.1 / time_s * tau ** 2

    def cycle(tau, hz):
        return 0.13 / (2 * math.pi * hz) * np.sin(2 * math.pi * hz * tau)
    for hz in (2.0, 2.5, 3.0):
        # braked in 0.3 s, then the limit cycle: at rest within a few hundredths of the wheels' stop
        stop = stop_time_s(t, travel(lambda tau: braking(tau) + cycle(tau, hz)), course)
        assert stop == pytest.approx(0.3, abs=0.05)
        # the limit cycle alone from the command on (a stop in no time): within half the window
        assert stop_time_s(t, travel(lambda tau: cycle(tau, hz)), course) <= REST_WINDOW_S / 2
    # braked in 0.6 s: later
    assert stop_time_s(t, travel(lambda tau: braking(tau, 0.6)), course) == pytest.approx(0.6, abs=0.07)
    # creeping on after braking at 4 cm/s (beyond the speed's band): never at rest; at 1.5 cm/s
    # (within it, beyond the radius over the hold): only once too little of the segment is left
    assert stop_time_s(t, travel(lambda tau: braking(tau) + 0.04 * tau), course) is None
    assert stop_time_s(t, travel(lambda tau: braking(tau) + 0.015 * tau), course) > 3.0 - REST_WINDOW_S / 2 - 1.0
    # overshooting by 6 cm, then coming back over 1.5 s: at rest only once back
    back = stop_time_s(t, travel(lambda tau: braking(tau) - 0.06 * np.clip((tau - 0.3) / 1.5, 0.0, 1.0)), course)
    assert back == pytest.approx(1.8, abs=0.2)
    # a turn in place is no stop; no stop at all: None
    v_stop = travel(lambda tau: braking(tau))
    assert stop_time_s(t, v_stop, [(0.2, 0.0, 5.0), (0.0, 1.0, 3.0)]) is None
    assert stop_time_s(t, np.zeros_like(t), [(0.0, 0.0, 8.0)]) is None


def test_the_plan_view_draws_both_paths(tmp_path):
    c = tracking.commanded_path([(0.2, 0.0, 2.0), (0.0, 90.0, 1.0)], 0.0)
    fig, ax = plt.subplots()
    tracking.plan_view_plot(ax, c, c, "robot")
    assert [line.get_label() for line in ax.get_lines()][:2] == ["commanded", "robot"]
    fig.savefig(str(tmp_path / "plan.png"))
    plt.close(fig)
    assert (tmp_path / "plan.png").stat().st_size > 1000


def test_a_course_driven_with_the_firmware_in_the_loop():
    # the ideal brick: the drive plan tracked to a few centimetres, 0.2 m/s reached and left
    from hostsim.sim import metrics
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.scenario import load_scenario
    base = load_scenario("drive_straight")
    sc = dataclasses.replace(base, brick=dataclasses.replace(base.brick, **{
        f.name: f.default for f in dataclasses.fields(base.brick) if f.name != "sources"}),
        x0_si=(0.0,) * 10)
    run = run_firmware(sc, sysfs=False)
    m = metrics.compute(run, sc, 7.6)
    t = m["tracking"]
    v = 0.5 * (run.x[:, 5] + run.x[:, 6])
    cruise = (run.t_s > 3.0) & (run.t_s < 5.0)
    assert m["completed"] and m["saturated_fraction"] == 0.0
    assert abs(v[cruise].mean() - 0.2) < 0.02 and t["max_speed_mps"] < 0.4
    assert t["rms_cross_track_m"] < 0.02 and t["final_position_error_m"] < 0.03
    assert t["final_heading_error_deg"] < 2.0


def test_a_course_beyond_the_gains_is_refused_before_the_run():
    from hostsim.errors import TipbotError
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.scenario import load_scenario
    sc = dataclasses.replace(load_scenario("drive_straight"), course=((0.4, 0.0, 5.0),))
    with pytest.raises(TipbotError, match=r"field course\[0\]\.speed_mps must be a number in"):
        run_firmware(sc)
