"""A course file: timed drive segments, read and checked against the gains' limits.

The file (docs/course-format.md) is a JSON list of segments, each

    {"speed_mps": 0.2, "yaw_rate_dps": 0, "duration_s": 5}

run one after another from the let-go cue; after the last one the robot comes to rest and
balances there. A segment the robot cannot do is refused, never clipped: a speed or yaw rate
beyond the gains' `kalman.reference.limits`, or both at once beyond their shared budget (each
wheel's feedforward voltage is the forward and the turning share added: |v|/v_max + |w|/w_max
at most 1). Errors are one line naming the file and the field (``course.json: field
[2].speed_mps ...``). Python 3.5, standard library only.
"""
import math

from tipbot_fw import fields

SEGMENT_FIELDS = ('speed_mps', 'yaw_rate_dps', 'duration_s')
MAX_SEGMENTS = 1000
# The whole plan is made before the run (tipbot_fw.drive.plan): 48 bytes a tick, 1.2 MB for two minutes
MAX_COURSE_S = 120.0


def transition_s(dv, a_max, j_max):
    """The smoothstep's duration for a change dv (tipbot_fw.drive.plan's docstring); 0 for no change."""
    dv = abs(dv)
    if dv == 0.0:
        return 0.0
    return max(1.5 * dv / a_max, math.sqrt(6.0 * dv / j_max))


def channel_limits(limits):
    """((a_max, j_max) forward in m/s^2, m/s^3, (alpha_max, yaw jerk) in rad/s^2, rad/s^3)."""
    return ((limits['accel_mps2'], limits['jerk_mps3']),
            (math.radians(limits['yaw_accel_dps2']), math.radians(limits['yaw_jerk_dps3'])))


class CourseError(ValueError):
    """An invalid course file; the message names the file and the field."""


def parse_course(doc, source, limits, prefix=''):
    """[(speed_mps, yaw_rate_rad_s, duration_s)] of a parsed course document, checked against
    limits (the gains' kalman.reference.limits: speed_mps, yaw_rate_dps); prefix: the course's
    field in another file (a scenario's `course`)."""
    f = fields.Fields(source, CourseError, prefix)
    problem = None
    if not isinstance(doc, list) or not doc:
        problem = ('must be a JSON list of segments ({"speed_mps": ..., "yaw_rate_dps": ..., "duration_s": ...}), '
                   'at least one')
    elif len(doc) > MAX_SEGMENTS:
        problem = 'has {} segments, more than the {} a course may have'.format(len(doc), MAX_SEGMENTS)
    if problem:
        if prefix:
            f.fail('', problem)
        raise CourseError('{}: {}'.format(source, problem))
    v_max, w_max = limits['speed_mps'], limits['yaw_rate_dps']
    fwd, yaw_lim = channel_limits(limits) if 'accel_mps2' in limits else (None, None)
    previous = (0.0, 0.0)
    total = 0.0
    out = []
    for i, seg in enumerate(doc):
        at = '[{}].'.format(i)
        f.check(at[:-1], seg, fields.obj)
        f.known(seg, SEGMENT_FIELDS, at)
        f.require(seg, SEGMENT_FIELDS, at)
        speed = f.number(at + 'speed_mps', seg['speed_mps'], lo=-v_max, hi=v_max, lo_open=False)
        yaw = f.number(at + 'yaw_rate_dps', seg['yaw_rate_dps'], lo=-w_max, hi=w_max, lo_open=False)
        duration = f.number(at + 'duration_s', seg['duration_s'], lo=0.0, hi=MAX_COURSE_S)
        share = abs(speed) / v_max + abs(yaw) / w_max
        if share > 1.0 + 1e-9:
            f.fail(at + 'speed_mps', 'and yaw_rate_dps together ask for {:.0f} % of the drive budget (|speed| / '
                   '{:.3g} m/s + |yaw rate| / {:.3g} deg/s must be at most 1: these gains\' limits)'.format(
                       100.0 * share, v_max, w_max))
        yaw_rad = math.radians(yaw)
        if fwd is not None:
            # its own change of speed and of yaw rate must be over before the next one starts
            need = max(transition_s(speed - previous[0], *fwd), transition_s(yaw_rad - previous[1], *yaw_lim))
            if duration < need - 1e-9:
                f.fail(at + 'duration_s', 'is {:g} s, shorter than the {:.2f} s its change of speed and yaw rate '
                       'takes within these gains\' acceleration and jerk limits'.format(duration, need))
        total += duration
        if total > MAX_COURSE_S:
            f.fail(at + 'duration_s', 'makes the course {:g} s long: at most {:g} s (its plan is made before the '
                   'run)'.format(total, MAX_COURSE_S))
        previous = (speed, yaw_rad)
        out.append((speed, yaw_rad, duration))
    return out


def read_course(path, limits):
    """The checked segments of the course file at path (parse_course)."""
    doc = fields.read_json(path, CourseError)[0]
    return parse_course(doc, path, limits)

