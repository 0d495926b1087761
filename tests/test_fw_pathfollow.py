"""Following a course in the plane (tipbot_fw.drive.pathfollow): the pose arithmetic, the offsets a lag
at a turn in place makes, rows that are the course's own when the robot follows exactly, and the
square driven on the realistic brick."""
import math

import pytest

import fw_support as S
from conftest import PHYSICAL_GAINS
from tipbot_fw.drive import pathfollow as pf
from tipbot_fw.gains import load_gains
from tipbot_fw.cores.kalman import REF, KalmanCore


@pytest.fixture(scope='module')
def physical():
    return load_gains(PHYSICAL_GAINS)


def test_odometry_of_a_quarter_circle_and_the_error_in_the_robots_frame():
    track = 0.1
    o = pf.Odometry(track)
    r, steps = 0.5, 400
    for i in range(1, steps + 1):            # a left arc of radius r through 90 degrees
        a = 0.5 * math.pi * i / steps
        o.to((r + track / 2) * a, (r - track / 2) * a)
    assert (o.x, o.y, o.heading) == pytest.approx((r, r, 0.5 * math.pi), abs=1e-5)
    ref = pf.Pose(o.x, o.y + 0.03, o.heading)              # the reference 3 cm further along +y
    e_x, e_y, e_h = pf.planar_error(o, ref)
    assert (e_x, e_y, e_h) == pytest.approx((0.03, 0.0, 0.0), abs=1e-9)   # ahead: the robot faces +y
    ref = pf.Pose(o.x - 0.02, o.y, o.heading)               # 2 cm to its left (-x, facing +y)
    assert pf.planar_error(o, ref)[:2] == pytest.approx((0.0, 0.02), abs=1e-9)


def core_and_follower(gains, course):
    core = KalmanCore(gains, S.fw_config())
    core.set_gyro_bias(0.0)
    core.set_battery(8.0)
    return core, pf.follow_course(gains, core, course)


def test_followed_exactly_the_rows_are_the_courses_own(physical):
    core, f = core_and_follower(physical, [(0.2, 0.0, 2.0)])
    f.update(1)                                  # at rest at the start, the reference too
    assert (f.common, f.steer) == (0.0, 0.0)
    f.fill()
    assert list(f.rows) == f.plan_rows[:pf.LOOKAHEAD_TICKS]


def test_a_lag_at_a_turn_in_place_is_not_made_up_along_the_new_heading(physical):
    # the reference went 1 m ahead and turned 90 degrees left in place; the robot stopped 4 cm
    # short and turned too: its wheels are 4 cm behind theirs, but along its new heading it is on
    # the path's line's extension, 4 cm to the side: the common offset takes the 4 cm out of the
    # wheels' error, the steering (scaled by the reference's speed: here at rest) waits
    core, f = core_and_follower(physical, [(0.2, 0.0, 5.0), (0.0, math.pi / 2, 1.0), (0.0, 0.0, 2.0)])
    k = int(round(7.5 / physical.ts_s))          # after the turn, at rest
    row = REF.unpack_from(f.plan, REF.size * (k - 1))
    d_ref = (row[0] * f.lsb[0], row[1] * f.lsb[1])
    s_ref, turn = 0.5 * (d_ref[0] + d_ref[1]), 0.5 * (d_ref[0] - d_ref[1])
    assert turn / f.h == pytest.approx(math.pi / 2, abs=1e-3)
    f.robot = pf.Odometry(2 * f.h)
    f.robot.to(s_ref - 0.04, s_ref - 0.04)                    # driven 4 cm short
    f.robot.to(s_ref - 0.04 + turn, s_ref - 0.04 - turn)      # then the turn
    core.wheel_positions = lambda: (s_ref - 0.04 + turn, s_ref - 0.04 - turn)
    for _ in range(100):                                      # the offsets' slew: several updates
        f.update(k)
    # the wheels' 4 cm lag taken out, but for what the reference itself moved along the new
    # heading while it turned (its speed's ramp to zero overlaps the turn's start: 3 mm)
    e_x = pf.planar_error(f.robot, f._ref_at(k - 1))[0]
    assert abs(e_x) < 0.005 and f.common == pytest.approx(e_x - 0.04, abs=1e-6)
    assert f.steer == pytest.approx(0.0, abs=1e-9)            # at rest: no steering yet


@pytest.mark.slow
def test_the_square_on_the_realistic_brick_ends_where_it_started():
    # issue 21's square, seed 0 of scenarios/drive_square.json: within 5 cm and 5 degrees of its
    # start (the wheels' own tracking alone ended 10 cm away: docs/course-format.md)
    from hostsim.sim import metrics
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.scenario import load_scenario
    sc = load_scenario("drive_square")
    run = run_firmware(sc, sysfs=True)
    t = metrics.compute(run, sc, 7.6)["tracking"]
    assert t["final_position_error_m"] < 0.05 and t["final_heading_error_deg"] < 5.0
    assert t["rms_cross_track_m"] < 0.04
