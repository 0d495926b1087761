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


def test_the_stop_time_runs_from_the_reference_at_zero_to_the_wheels_at_rest():
    """metrics.stop_time_s: a course of 0.2 m/s for 5 s then 2 s of rest; the reference reaches
    zero at 5 s plus its smoothstep (T from the limits), the wheels' 0.1 s mean must then stay
    within 0.05 m/s for 0.5 s."""
    from hostsim.sim.metrics import stop_time_s
    from tipbot_fw.drive.course import transition_s
    lim = (0.6, 3.0)
    t_zero = 5.0 + transition_s(0.2, *lim)
    t = np.arange(0.0, 7.0, 0.005)
    course = [(0.2, 0.0, 5.0), (0.0, 0.0, 2.0)]
    # at rest 0.3 s after the reference: a decaying overshoot, then still
    v = np.where(t < t_zero, 0.2, np.where(t < t_zero + 0.3, -0.1, 0.0))
    # + 0.05 s: the 0.1 s mean of -0.1 m/s and rest is within 0.05 m/s half-way
    assert stop_time_s(t, v, course, lim) == pytest.approx(0.3 + 0.05, abs=0.011)
    # rocking at 0.08 m/s, 2.5 Hz, after the stop: never at rest
    rocking = np.where(t < t_zero, 0.2, 0.08 * np.sin(2 * math.pi * 2.5 * t))
    assert stop_time_s(t, rocking, course, lim) is None
    # a turn in place is no stop; no stop at all: None
    assert stop_time_s(t, v, [(0.2, 0.0, 5.0), (0.0, 1.0, 2.0)], lim) is None
    assert stop_time_s(t, np.zeros_like(t), [(0.0, 0.0, 7.0)], lim) is None


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
