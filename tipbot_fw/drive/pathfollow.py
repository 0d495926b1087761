"""Following a course in the plane: the wheels' reference corrected from the robot's pose.

The law tracks each wheel's reference (tipbot_fw.cores.kalman). Tracking both wheels is tracking the
path only while the robot's heading is the reference's: a robot some centimetres behind when the
course turns in place makes those centimetres up along the NEW heading (each side of a square
comes out short or long by the last one's lag, and the path beside the reference by as much).
So a course is followed in the plane, as unicycle path trackers do (Kanayama et al., 1990): in the
loop's slack, every UPDATE_TICKS, the robot's pose (x, y, heading) from its wheels (the filter's
d^_r, d^_l: the odometry of the encoders) is compared with the reference's pose (the same
odometry of the reference's wheels), the error taken in the robot's frame

    e_x = along-track (ahead of the robot),  e_y = cross-track (to its left),  e_h = heading,

and the wheels' reference is moved by two offsets, so that what the wheel law acts on is that
error and not the wheels' own: the common-mode offset makes the wheels' mean error e_x (not the
distance each wheel is behind: after a turn in place the distance is across the new heading),
and the heading gets a steering term e_y / LOOKAHEAD_M (at most STEER_MAX_RAD), scaled by the
reference's speed over its top speed, with its sign (a robot at rest does not turn towards a
line it cannot reach by turning, and ends with the course's heading; one backing up turns the
other way). Each offset moves to its new value at most
at SLEW (a step in the reference would be a jolt to the lean). When the robot follows exactly,
both are zero and the rows are the course's own.

The rows are made in the slack as a remote's are (tipbot_fw.drive.remote: a deque the core takes one
row a tick from, KalmanCore.set_live, LOOKAHEAD_TICKS ahead), from the course's plan made
before the run (tipbot_fw.drive.plan); the log records the rows the core got, so a replay is exact.

Python 3.5, numpy 1.12.
"""
import array
import collections
import math

import numpy as np

from tipbot_fw.cores.kalman import REF, ref_rows

UPDATE_TICKS = 20           # the pose compared every 20 ticks (10 Hz at 5 ms): well above the offsets' rate
# rows made ahead of the ticks: refilled to LOOKAHEAD_TICKS once fewer than REFILL_BELOW are left,
# in batches of 30 (numpy's overhead once, not each tick); a side task comes at least every 10
# ticks, so more than the 12 rows a skip keeps always remain
LOOKAHEAD_TICKS = 54
REFILL_BELOW = 24
LOOKAHEAD_M = 0.3           # steering: the heading towards the path, e_y / 0.3 m (1.5 s at 0.2 m/s)
STEER_MAX_RAD = 0.3         # at most 17 degrees off the course's heading
SLEW_MPS = 0.05             # the common-mode offset moves at most 5 cm/s
SLEW_RAD_S = 0.5            # the steering offset at most 0.5 rad/s
COMMON_MAX_M = 0.5          # and the common-mode offset at most half a metre (beyond: not a lag)


class Odometry(object):
    """A two-wheeled pose from its wheels' travel: heading = (d_r - d_l) / track, position the
    sum of the mean travel along the mean heading of each step (from (0, 0), heading 0)."""

    def __init__(self, track_m):
        self.track_m = float(track_m)
        self.x = self.y = 0.0
        self.s = 0.0
        self.heading = 0.0

    def to(self, d_r, d_l):
        s = 0.5 * (d_r + d_l)
        heading = (d_r - d_l) / self.track_m
        mid = 0.5 * (heading + self.heading)
        ds = s - self.s
        self.x += ds * math.cos(mid)
        self.y += ds * math.sin(mid)
        self.s, self.heading = s, heading


def planar_error(robot, ref):
    """(e_x, e_y, e_h): the reference's pose relative to the robot's, in the robot's frame."""
    dx, dy = ref.x - robot.x, ref.y - robot.y
    c, s = math.cos(robot.heading), math.sin(robot.heading)
    return c * dx + s * dy, -s * dx + c * dy, ref.heading - robot.heading


class Pose(object):
    def __init__(self, x, y, heading):
        self.x, self.y, self.heading = x, y, heading


def reference_poses(ints, lsb, track_m):
    """(x, y, heading) of the plan's reference at each of its ticks (float32 arrays, m and rad):
    Odometry's arithmetic at every tick, made once with numpy before the run."""
    d_r = ints[:, 0] * lsb[0]
    d_l = ints[:, 1] * lsb[1]
    heading = (d_r - d_l) / track_m
    ds = np.diff(np.concatenate([[0.0], 0.5 * (d_r + d_l)]))
    mid = 0.5 * (heading + np.concatenate([[0.0], heading[:-1]]))
    # as array('f'): an element read is a Python float at once (a numpy one costs ~2,000 instructions)
    return tuple(array.array('f', a.astype('<f4').tobytes())
                 for a in (np.cumsum(ds * np.cos(mid)), np.cumsum(ds * np.sin(mid)), heading))


def _slew(value, target, step):
    return value + max(-step, min(step, target - value))


def follow_course(gains, core, course, ahead=None):
    """A Kalman core (with these gains) set to drive `course` [(speed_mps, yaw_rate_rad_s,
    duration_s)]: its plan made (tipbot_fw.drive.plan.plan_for), the first rows filled (`ahead` of
    them, default LOOKAHEAD_TICKS) and handed to the core. -> the CourseFollower, whose side()
    the loop's slack runs."""
    from tipbot_fw.drive.plan import plan_for
    ref = gains.kalman.reference
    follower = CourseFollower(plan_for(gains, core, course), core, ref.track_m, ref.limits['speed_mps'], gains.ts_s)
    follower.fill(ahead)
    core.set_live(follower.rows)
    return follower


class CourseFollower(object):
    """The rows of a course's plan (bytes, tipbot_fw.drive.plan.course_plan) for a Kalman core, with the
    module docstring's offsets; `rows` is the deque KalmanCore.set_live takes."""

    def __init__(self, plan, core, track_m, top_speed_mps, period_s):
        self.plan = plan
        self.ints = np.frombuffer(plan, dtype='<i8').reshape(-1, 6)
        self.plan_rows = ref_rows(plan)
        self.core = core
        self.h = float(track_m) / 2.0
        self.lsb = (float(core.ref_lsb[0]), float(core.ref_lsb[1]))
        self.v_lsb = float(core.ref_lsb[2])
        self.v_top = float(top_speed_mps)
        self.robot = Odometry(track_m)
        self.ref_pose = reference_poses(self.ints, self.lsb, track_m)
        self.common = self.steer = 0.0     # the offsets applied (m, rad)
        self.dt = UPDATE_TICKS * float(period_s)
        self.rows = collections.deque()
        self.made = 0                      # rows made so far (the next is tick made + 1's)
        self.next_update = UPDATE_TICKS

    def _nominal(self, k):
        """The course's own reference row of tick k, Python ints (tick 0, the let-go: at rest at
        the start; the last one held after the course)."""
        if k <= 0:
            return (0, 0, 0, 0, 0, 0)
        return REF.unpack_from(self.plan, REF.size * (min(k, len(self.plan_rows)) - 1))

    def _ref_at(self, k):
        if k <= 0:
            return Pose(0.0, 0.0, 0.0)
        i = min(k, len(self.plan_rows)) - 1
        x, y, h = self.ref_pose
        return Pose(x[i], y[i], h[i])

    def update(self, k):
        """After k ticks (the last one tick k - 1): its pose against the reference's of that
        tick -> the offsets' new values."""
        x = self.core.wheel_positions()
        self.robot.to(x[0], x[1])
        row = self._nominal(k - 1)
        e_x, e_y, _ = planar_error(self.robot, self._ref_at(k - 1))
        wheels = 0.5 * ((row[0] * self.lsb[0] - x[0]) + (row[1] * self.lsb[1] - x[1]))
        # signed: backing up, turning towards the path moves the robot away from it
        speed = max(-1.0, min(1.0, 0.5 * (row[2] + row[3]) * self.v_lsb / self.v_top))
        steer = max(-STEER_MAX_RAD, min(STEER_MAX_RAD, e_y / LOOKAHEAD_M)) * speed
        # the wheels' mean error made e_x: the common offset is what the wheels' own lacks of it
        target = max(-COMMON_MAX_M, min(COMMON_MAX_M, e_x - wheels))
        self.common = _slew(self.common, target, SLEW_MPS * self.dt)
        self.steer = _slew(self.steer, steer, SLEW_RAD_S * self.dt)

    def fill(self, ahead=None):
        """Rows until `ahead` (default LOOKAHEAD_TICKS) wait for the ticks, with the offsets of now."""
        # the periods a stall skipped beyond the rows there were: the course keeps to the clock
        self.made += self.core.live_lag
        self.core.live_lag = 0
        n = (LOOKAHEAD_TICKS if ahead is None else ahead) - len(self.rows)
        if n <= 0:
            return
        k0, k1 = self.made, self.made + n         # plan indices (the row of tick k at k - 1)
        dr = int(round((self.common + self.steer * self.h) / self.lsb[0]))
        dl = int(round((self.common - self.steer * self.h) / self.lsb[1]))
        last = len(self.plan_rows)
        if dr == 0 and dl == 0 and k1 <= last:      # followed exactly: the course's own rows
            self.rows.extend(self.plan_rows[k0:k1])
        else:       # one numpy sum for the batch (the positions stay within the plan's range:
            # the offsets are bounded, the plan's positions are far inside +-top)
            part = self.ints[k0:k1] if k1 <= last else self.ints[np.minimum(np.arange(k0, k1), last - 1)]
            rows = part + np.array([dr, dl, 0, 0, 0, 0], dtype='<i8')
            self.rows.extend(ref_rows(rows.tobytes()))
        self.made = k1

    def side(self):
        """The side task: the pose every UPDATE_TICKS, the rows ahead when they run low; due
        again at the sooner of the two (a tick takes one row)."""
        def task(k):
            if k >= self.next_update:
                self.update(k)
                self.next_update = k + UPDATE_TICKS
            if len(self.rows) < REFILL_BELOW:
                self.fill()
            return min(self.next_update, k + 1 + len(self.rows) - REFILL_BELOW)
        return task
