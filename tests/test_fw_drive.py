"""Driving (issue 21): the drive reference's profiles, course files, the core's tracking term,
and a course run from the command line."""
import collections
import json
import math

import numpy as np
import pytest

import fw_support as S
from conftest import PAPER_GAINS, PHYSICAL_GAINS
from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw import cli
from tipbot_fw.cores import kalman
from tipbot_fw.drive import pathfollow
from tipbot_fw.config import load_config
from tipbot_fw.drive.course import CourseError, parse_course, read_course
from tipbot_fw.drive.plan import course_plan, transition_s
from tipbot_fw.gains import load_gains
from tipbot_fw.cores.kalman import KalmanCore, N_U
from tipbot_fw.record.logfile import read_log
from tipbot_fw.drive.pathfollow import follow_course

LIMITS = {'speed_mps': 0.25, 'accel_mps2': 0.6, 'jerk_mps3': 3.0, 'yaw_rate_dps': 100.0,
          'yaw_accel_dps2': 300.0, 'yaw_jerk_dps3': 1500.0}
DT = 0.005
LSB = [1e-9] * 6      # SI per integer: fine enough to read the plan back from its integers
TOP = 2 ** 62
H = 0.2


def plan_si(course):
    rows = np.frombuffer(course_plan(course, LIMITS, H, DT, LSB, TOP), dtype='<i8').reshape(-1, 6)
    return rows * 1e-9      # d_r, d_l, v_r, v_l, a_r, a_l per tick from tick 1


def forward_and_yaw(p):
    return (p[:, 0] + p[:, 1]) / 2, (p[:, 0] - p[:, 1]) / H, (p[:, 2] + p[:, 3]) / 2, (p[:, 2] - p[:, 3]) / H, \
        (p[:, 4] + p[:, 5]) / 2


def test_a_speed_change_keeps_the_limits_and_never_overshoots():
    p = plan_si([(0.2, 0.0, 3.0)])
    s, psi, v, w, a = forward_and_yaw(p)
    ramp = transition_s(0.2, 0.6, 3.0)
    k_ramp = int(ramp / DT) + 2
    assert v[k_ramp] == pytest.approx(0.2, abs=1e-6) and v.max() <= 0.2 + 1e-6
    assert np.all(np.diff(v[:int(3.0 / DT) - 1]) >= -1e-9)          # no dip on the way up
    assert np.abs(a).max() <= 0.6 + 1e-6 and np.abs(np.diff(a)).max() <= 3.0 * DT * 1.05
    assert np.allclose(np.diff(v), 0.5 * (a[1:] + a[:-1]) * DT, atol=5e-5)   # a is v's derivative
    assert abs(v[-1]) < 1e-6 and np.all(p[-1, 2:] == 0)             # at rest once the course ends


def test_the_course_covers_its_distance_and_heading():
    # each change is a smoothstep, so a segment's distance is its speed times its duration
    p = plan_si([(0.2, 0.0, 3.0), (0.0, math.radians(90), 1.0)])
    s, psi, v, w, a = forward_and_yaw(p)
    assert s[-1] == pytest.approx(0.6, abs=1e-4)
    assert math.degrees(psi[-1]) == pytest.approx(90.0, abs=0.01)
    assert np.abs(w).max() <= math.radians(90) + 1e-6


def test_the_wheels_follow_distance_and_heading():
    p = plan_si([(0.1, 0.5, 2.0)])
    s, psi, v, w, a = forward_and_yaw(p)
    k = 300
    assert p[k, 0] == pytest.approx(s[k] + psi[k] * H / 2, abs=1e-8)
    assert (p[k, 2], p[k, 3]) == (pytest.approx(0.1 + 0.5 * H / 2, abs=1e-6), pytest.approx(0.1 - 0.5 * H / 2, abs=1e-6))


def test_a_stall_moves_the_plan_on_by_its_periods(physical):
    # the course keeps to the clock: a stall's periods are skipped in its rows (the deque's, and
    # beyond them its follower's), as the ticks they were for passed
    (a, b), buf = core_pair(physical)
    followers = [follow_course(physical, c, [(0.2, 0.0, 2.0)]) for c in (a, b)]
    for _ in range(100):
        step_followed(a, followers[0], buf)
    for _ in range(40):
        step_followed(b, followers[1], buf)
    b.skip(59)
    step_followed(b, followers[1], buf, fill_first=True)
    # the 12 rows a skip keeps come first (tipbot_fw.cores.kalman.LIVE_KEEP_ROWS), then the clock's
    for _ in range(kalman.LIVE_KEEP_ROWS):
        step_followed(b, followers[1], buf)
    for _ in range(kalman.LIVE_KEEP_ROWS):
        step_followed(a, followers[0], buf)
    assert a.reference() == b.reference() and a.reference()[2] > 0.1
    b.skip(1000)            # beyond its end: the last row, at rest, is held
    step_followed(b, followers[1], buf, fill_first=True)
    for _ in range(kalman.LIVE_KEEP_ROWS):
        step_followed(b, followers[1], buf)
    assert b.reference()[2:] == [0.0] * 4 and b.reference()[0] > 0.3


def step_followed(core, follower, buf, fill_first=False):
    """One tick of a course's core, its follower's rows topped up first (as the slack does)."""
    if fill_first or len(follower.rows) < pathfollow.REFILL_BELOW:
        follower.fill()
    core.step((0, 0, 0, 0), (0, 0), buf, 0)


# -- course files
def write(tmp_path, doc, name='course.json'):
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return str(p)


def test_a_course_file_reads_as_segments(tmp_path):
    path = write(tmp_path, [{'speed_mps': 0.2, 'yaw_rate_dps': 0, 'duration_s': 5},
                            {'speed_mps': 0, 'yaw_rate_dps': -90, 'duration_s': 1}])
    assert read_course(path, LIMITS) == [(0.2, 0.0, 5.0), (0.0, math.radians(-90), 1.0)]


def test_a_course_file_saved_with_a_byte_order_mark_reads(tmp_path):
    """Windows' Notepad saves UTF-8 with a BOM: the same course."""
    p = tmp_path / 'bom.json'
    p.write_bytes(b'\xef\xbb\xbf' + json.dumps([{'speed_mps': 0.2, 'yaw_rate_dps': 0, 'duration_s': 5}]).encode())
    assert read_course(str(p), LIMITS) == [(0.2, 0.0, 5.0)]


@pytest.mark.parametrize('doc, words', [
    ({'speed_mps': 0.1}, 'must be a JSON list of segments'),
    ([], 'must be a JSON list of segments'),
    ([{'speed_mps': 0.1, 'yaw_rate_dps': 0}], 'field [0].duration_s is missing'),
    ([{'speed_mps': 0.1, 'yaw_rate_dps': 0, 'duration_s': 1, 'turbo': 1}], 'field [0].turbo is unknown'),
    ([{'speed_mps': 0.1, 'yaw_rate_dps': 0, 'duration_s': 1},
      {'speed_mps': 0.3, 'yaw_rate_dps': 0, 'duration_s': 1}], 'field [1].speed_mps must be a number in [-0.25, 0.25]'),
    ([{'speed_mps': 0, 'yaw_rate_dps': 120, 'duration_s': 1}], 'field [0].yaw_rate_dps must be a number in'),
    ([{'speed_mps': 0.2, 'yaw_rate_dps': 50, 'duration_s': 1}], 'field [0].speed_mps and yaw_rate_dps together ask '
                                                                'for 130 % of the drive budget'),
    ([{'speed_mps': 0.1, 'yaw_rate_dps': 0, 'duration_s': 0}], 'field [0].duration_s must be a number in (0.0'),
    ([{'speed_mps': 0.2, 'yaw_rate_dps': 0, 'duration_s': 0.3}], 'field [0].duration_s is 0.3 s, shorter than the 0.63 s'),
    ([{'speed_mps': 0.1, 'yaw_rate_dps': 0, 'duration_s': 100}, {'speed_mps': 0, 'yaw_rate_dps': 0, 'duration_s': 30}],
     'field [1].duration_s makes the course 130 s long: at most 120 s'),
    ([{'speed_mps': True, 'yaw_rate_dps': 0, 'duration_s': 1}], 'field [0].speed_mps must be a number'),
])
def test_a_course_the_robot_cannot_do_is_refused_by_file_and_field(tmp_path, doc, words):
    path = write(tmp_path, doc)
    with pytest.raises(CourseError) as e:
        read_course(path, LIMITS)
    msg = str(e.value)
    assert msg.startswith(path + ': ') and words in msg and '\n' not in msg, msg


def test_a_course_in_another_file_is_named_by_its_field():
    with pytest.raises(CourseError, match=r'^s.json: field course\[0\].speed_mps must be'):
        parse_course([{'speed_mps': 9, 'yaw_rate_dps': 0, 'duration_s': 1}], 's.json', LIMITS, 'course')
    with pytest.raises(CourseError, match=r'^s.json: field course must be a JSON list'):
        parse_course({}, 's.json', LIMITS, 'course')


# -- the core's tracking term
@pytest.fixture(scope='module')
def physical():
    return load_gains(PHYSICAL_GAINS)


def core_pair(gains):
    config = load_config()
    cores = [KalmanCore(gains, config) for _ in range(2)]
    for c in cores:
        c.set_gyro_bias(0.0)
        c.set_battery(8.0)
        buf = bytearray(c.rows.row_bytes)
        c.start((0, 0, 0, 0), (0, 0), buf, 0)
    return cores, bytearray(cores[0].rows.row_bytes)


def test_standing_the_reference_changes_nothing(physical):
    (a, b), buf = core_pair(physical)
    b.set_live(collections.deque([bytes(48)] * 200))    # driving the whole product, on a reference at zero
    rng = np.random.default_rng(0)
    for k in range(200):
        enc = tuple(int(v) for v in rng.integers(-3, 4, size=4))
        gyro = (0, int(rng.integers(-20, 21)))
        assert a.step(enc, gyro, buf, 0) == b.step(enc, gyro, buf, 0)
    assert list(a.v) == list(b.v)


def test_the_reference_enters_the_duties_as_the_law_says(physical):
    """u = -K_a (x^ - x_ref) + u_ff: the duties move by K_a's wheel-position columns times the
    reference positions plus G r, to the duty's rounding; the filter's state does not move."""
    (a, b), buf = core_pair(physical)
    ref = physical.kalman.reference
    d_ref, r = np.array([0.01, -0.004]), np.array([0.1, 0.05, 0.2, -0.1])
    ints = [int(round(d_ref[i] / b.ref_lsb[i])) for i in (0, 1)] + [int(round(r[i] / b.ref_lsb[2 + i]))
                                                                   for i in range(4)]
    b.set_reference(ints)
    da, _ = a.step((1, 2, 0, 0), (0, 3), buf, 0)
    db, _ = b.step((1, 2, 0, 0), (0, 3), buf, 0)
    kal = physical.kalman
    k_a, nf = kal.K, kal.n_filter
    # the integrators take in -ts d_ref this tick (z integrates d^ - d_ref), the law -K_z of that
    volts = (k_a[:, 0:2] + physical.ts_s * k_a[:, nf:]).dot(d_ref) + ref.G.dot(r)
    expected = [volts[i] * 100.0 / 8.0 * b.polarity[i] for i in range(N_U)]
    assert all(abs((db[i] - da[i]) - expected[i]) <= 1.0 for i in range(N_U)), (da, db, expected)
    assert max(abs(e) for e in expected) > 5       # a test that sees the term
    assert nf == kal.n - 2 and list(a.v[N_U:N_U + nf]) == list(b.v[N_U:N_U + nf])
    dz = [(int(b.v[N_U + nf + i]) - int(a.v[N_U + nf + i])) * float(b.state_lsb[nf + i]) for i in (0, 1)]
    assert dz == pytest.approx(list(-physical.ts_s * d_ref), abs=float(b.state_lsb[nf]))   # to its resolution


def test_gains_without_a_reference_cannot_drive(tmp_path, capsys):
    doc = json.load(open(PHYSICAL_GAINS))
    del doc['kalman']['reference']
    old = S.write_json(tmp_path / 'old.json', doc)
    course = write(tmp_path, [{'speed_mps': 0.1, 'yaw_rate_dps': 0, 'duration_s': 1}])
    assert cli.main(['run', '--gains', old, '--course', course, '--sysfs-root', str(tmp_path / 'none')]) == 2
    err = capsys.readouterr().err
    assert 'cannot drive' in err and 'kalman.reference' in err and 'make gains' in err


# -- a course run from the command line
@pytest.fixture
def fake(tmp_path):
    f = FakeEV3(str(tmp_path / 'sys'), battery_v=8.2)
    f.set_readings((0, 0, 0, 0))
    yield f
    f.close()


def test_run_with_a_course_logs_the_reference_and_replays_exactly(fake, tmp_path, capsys):
    from tipbot_fw.record.replay import replay
    config = S.write_json(tmp_path / 'quick.json',
                          {'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})
    course = write(tmp_path, [{'speed_mps': 0.2, 'yaw_rate_dps': 10, 'duration_s': 0.7}])
    log = str(tmp_path / 'run.log')
    code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', config, '--duration', '0.4',
                     '--log', log, '--sysfs-root', fake.sysfs_root, '--course', course])
    assert code == 0, capsys.readouterr().err
    header, rows = read_log(log)
    assert header['course'] == [{'speed_mps': 0.2, 'yaw_rate_dps': pytest.approx(10.0), 'duration_s': 0.7}]
    names = [c['name'] for c in header['columns']]
    v_r = rows[:, names.index('ref_v_r')]
    assert v_r[0] == 0 and 0 < v_r.max() < 0.2 + 10 * math.pi / 180 * 0.13     # ramping up
    assert rows[-1, names.index('ref_d_r')] > rows[-1, names.index('ref_d_l')] > 0   # turning left
    again = replay(header, rows, load_gains(PHYSICAL_GAINS))
    assert np.array_equal(again[:, 2:], rows[:, 2:])


def test_the_paper_gains_drive_too(capsys, tmp_path):
    g = load_gains(PAPER_GAINS)
    assert g.kalman.reference is not None and g.kalman.reference.limits['speed_mps'] > 0.1


def test_the_replayed_law_output_includes_the_reference(fake, tmp_path, capsys):
    # replay.signals' u_cmd is the law's output before rounding: with a course, the logged duties
    # are those of -K_a x^ + K_a d_ref + G r (to the duty's rounding), not of -K_a x^ alone
    from tipbot_fw.record.replay import signals
    config = S.write_json(tmp_path / 'quick.json',
                          {'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})
    course = write(tmp_path, [{'speed_mps': 0.2, 'yaw_rate_dps': 0, 'duration_s': 1.0}])
    log = str(tmp_path / 'run.log')
    assert cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', config, '--duration', '0.5',
                     '--log', log, '--sysfs-root', fake.sysfs_root, '--course', course]) == 0
    header, rows = read_log(log)
    sig = signals(header, rows, load_gains(PHYSICAL_GAINS))
    applied, law = sig.u[1:, [0, 1, 3, 4]], sig.u_cmd[1:, [0, 1, 3, 4]]
    duty_v = 8.2 / 100.0
    inside = np.abs(law) < 7.0          # not saturated
    assert inside.sum() > 100
    assert np.abs(applied[inside] - law[inside]).max() <= duty_v * 0.5 + 1e-6
    assert np.abs(sig.reference[:, 2]).max() > 0.1
