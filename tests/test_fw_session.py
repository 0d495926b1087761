"""tipbot_fw.session + safety: every way a run ends leaves the motors stopped and the log written."""
import os
import re
import signal

import numpy as np
import pytest

import fw_support as S
from tipbot_fw.calibration import sample_counts
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cues import OwnerCues
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.record.logfile import read_log
from tipbot_fw.session import run_session
from tipbot_fw.cores.detector_rows import DetectorRows
from tipbot_fw.vocabulary import FLAG_BITS

col = DetectorRows.col

FALL, JOINT_LIMIT, OVERRUN = FLAG_BITS['fall'], FLAG_BITS['joint_limit'], FLAG_BITS['overrun']


def session(tmp_path, dev, clock=None, duration_s=1.0, config=None):
    log_path = str(tmp_path / 'run.log')
    messages = []
    code, header = run_session(dev, S.load(), config or S.fw_config(), clock or VirtualClock(),
                               log_path=log_path, duration_s=duration_s, say=messages.append)
    return code, header, log_path, messages


def assert_stopped_and_logged(dev, log_path, reason, code, header):
    assert dev.stop_calls >= 1 and dev.duties == [0, 0, 0, 0]
    h, rows = read_log(log_path)
    assert h['stop_reason'] == reason and h['exit_code'] == code == header['exit_code']
    assert rows.shape == (h['ticks'] - h['first_tick'], len(h['columns']))
    return h, rows


def col_of(h, name):
    return [c['name'] for c in h['columns']].index(name)


TickCounter = S.TickCounter


def test_completed_run(tmp_path):
    dev = MemoryDevices()
    code, header, path, msgs = session(tmp_path, dev, duration_s=0.5)
    h, rows = assert_stopped_and_logged(dev, path, 'completed', 0, header)
    assert h['ticks'] == 100 and msgs[-1] == 'stopped: completed (exit 0, 100 ticks); log {}'.format(path)
    assert dev.closed is False          # closing the devices is the caller's (cli's) job


def test_fall_stops_the_motors_in_the_same_tick(tmp_path):
    dev = MemoryDevices()
    dev.trace = []
    # link 1 tips over at 100 deg/s once the loop runs: beyond 0.6 rad after ~0.35 s
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: setattr(dev, 'gyro', (0, 100))))
    code, header, path, msgs = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'fall', 6, header)
    th1 = rows[:, col_of(h, 'xi_th1')]                      # the Kalman filter's tilt estimate
    assert th1[-1] > 0.6 and np.all(th1[:-1] <= 0.6)       # stopped at the first tick beyond
    assert int(rows[-1, col_of(h, 'flags')]) & FALL
    last_tick = dev.trace[len(dev.trace) - 1 - dev.trace[::-1].index('read_raw'):]
    assert last_tick == ['read_raw', 'stop_all']             # no duty written in that tick
    assert 'fall: th1 = 0.60' in h['stop_message'] or 'fall: th1 = 0.61' in h['stop_message']


def test_joint_limit_stops_too(tmp_path):
    dev = MemoryDevices()
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: setattr(dev, 'enc', (0, 0, 0, 5 * n))))
    code, header, path, _ = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'joint_limit', 6, header)
    th3 = rows[:, col_of(h, 'enc_3')] * 2 * np.pi / 360
    assert abs(th3[-1]) > 1.2 and np.all(np.abs(th3[:-1]) <= 1.2)
    assert int(rows[-1, col_of(h, 'flags')]) & JOINT_LIMIT
    assert 'th3 = 1.22' in h['stop_message']


def test_the_detector_core_stops_at_the_limits_too(tmp_path):
    dev = MemoryDevices()
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: setattr(dev, 'enc', (0, 0, 0, 5 * n))))
    code, header, path, _ = session(tmp_path, dev, clock, config=S.fw_config(estimator='detector'))
    h, rows = assert_stopped_and_logged(dev, path, 'joint_limit', 6, header)
    assert h['estimator'] == 'detector' and [c['name'] for c in h['columns']] == DetectorRows.column_names
    assert abs(rows[-1, col('y_th3')]) > 1.2 and int(rows[-1, col('flags')]) & JOINT_LIMIT


def test_exception_in_the_tick(tmp_path):
    dev = MemoryDevices()
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: n == 30 and setattr(dev, 'enc', (None, 0, 0, 0))))
    code, header, path, msgs = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'exception', 1, header)
    assert h['stop_message'].startswith('TypeError') and h['ticks'] == 30


def test_sensor_read_failure(tmp_path):
    dev = MemoryDevices()

    def fail(n):
        if n == 40:
            def broken():
                raise OSError(19, 'No such device')
            dev.source = broken

    code, header, path, msgs = session(tmp_path, dev, VirtualClock(on_sleep=TickCounter(dev, fail)))
    h, rows = assert_stopped_and_logged(dev, path, 'device_failure', 5, header)
    assert 'read_raw failed at tick 40' in h['stop_message'] and len(rows) == 40


def test_write_failure(tmp_path):
    class FailingWrites(MemoryDevices):
        def write_duties(self, duties):
            if self.write_calls == 10:
                raise OSError(5, 'Input/output error')
            MemoryDevices.write_duties(self, duties)

    dev = FailingWrites()
    code, header, path, _ = session(tmp_path, dev)
    h, _ = assert_stopped_and_logged(dev, path, 'device_failure', 5, header)
    assert 'write_duties failed at tick 10' in h['stop_message']


def test_sigterm(tmp_path):
    dev = MemoryDevices()
    before = signal.getsignal(signal.SIGTERM)
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: n == 50 and os.kill(os.getpid(), signal.SIGTERM)))
    code, header, path, _ = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'sigterm', 143, header)
    assert 50 <= h['ticks'] <= 51
    assert signal.getsignal(signal.SIGTERM) == before


def test_sighup_from_a_dropped_ssh_session_stops_the_motors(tmp_path):
    dev = MemoryDevices()
    before = signal.getsignal(signal.SIGHUP)
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: n == 30 and os.kill(os.getpid(), signal.SIGHUP)))
    code, header, path, _ = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'sigterm', 143, header)
    assert 'SIGHUP' in h['stop_message']
    assert signal.getsignal(signal.SIGHUP) == before


def test_keyboard_interrupt(tmp_path):
    dev = MemoryDevices()

    def interrupt(n):
        if n == 20:
            raise KeyboardInterrupt

    code, header, path, _ = session(tmp_path, dev, VirtualClock(on_sleep=TickCounter(dev, interrupt)))
    assert_stopped_and_logged(dev, path, 'keyboard_interrupt', 130, header)


def test_a_second_signal_cannot_interrupt_the_shutdown(tmp_path):
    class SignalledStop(MemoryDevices):
        def stop_all(self):
            os.kill(os.getpid(), signal.SIGINT)     # Ctrl-C again while stopping
            MemoryDevices.stop_all(self)

    dev = SignalledStop()
    clock = VirtualClock(on_sleep=TickCounter(dev, lambda n: n == 5 and os.kill(os.getpid(), signal.SIGTERM)))
    code, header, path, _ = session(tmp_path, dev, clock)
    assert_stopped_and_logged(dev, path, 'sigterm', 143, header)


def test_overruns(tmp_path):
    dev = MemoryDevices()
    clock = VirtualClock()
    clock.on_sleep = TickCounter(dev, lambda n: n >= 10 and clock.advance(0.02))
    code, header, path, _ = session(tmp_path, dev, clock)
    h, rows = assert_stopped_and_logged(dev, path, 'overruns', 7, header)
    # each tick from the 10th on 15 ms late (3 periods skipped): besides the longest hold, more
    # than 40 ms lost at the fifth; every skipped period counted, the stopping tick's too
    assert re.match(r'the loop is behind: \d\d\.\d ms lost within 0.3 s besides its longest hold of 15.0 ms',
                    h['stop_message'])
    assert h['loop']['max_consecutive_overruns'] == 5 and 0.04 < h['loop']['max_lost_s'] < 0.06
    assert h['loop']['skipped_periods'] == 14 and '14 periods skipped' in h['stop_message']
    assert all(int(f) & OVERRUN for f in rows[-5:, col_of(h, 'flags')])
    assert not any(int(f) & OVERRUN for f in rows[:-5, col_of(h, 'flags')])


def test_low_battery_refuses_to_start(tmp_path):
    dev = MemoryDevices(battery_v=6.2)
    code, header, path, msgs = session(tmp_path, dev)
    h, rows = assert_stopped_and_logged(dev, path, 'low_battery', 4, header)
    assert dev.raw_reads == 0 and dev.write_calls == 0 and len(rows) == 0
    assert '6.20 V is below limits.min_battery_v = 6.5 V' in h['stop_message']


def calibration_source(dev, sample):
    """dev's readings during calibration: sample(i, used) -> (gyro angle, rate) for the i-th read,
    ``used`` False for the settle samples the calibration reads and does not use."""
    settle, _ = sample_counts(S.fw_config()['gyro_calibration'], S.load().ts_s)
    reads = iter(range(100000))

    def source():
        i = next(reads)
        return (0, 0, 0, 0), sample(i - settle, i >= settle)
    dev.source = source


@pytest.mark.parametrize('sample, message', [
    # the rate jumps: the robot moved
    (lambda i, used: (0, [0, 1, 0, 9][i] if used and i < 4 else 0), 'gyro rate varied by 9 deg/s'),
    # 50 deg/s in rate and angle alike: as consistent as a bias, but no held robot's bias
    (lambda i, used: (i // 4, 50), 'gyro read a steady 50.0 deg/s during calibration '
                                   '(gyro_calibration.max_bias_dps is 5)'),
    # the angle jumps 4 deg in the middle of the window; no rate sample saw the knock
    (lambda i, used: (4 if i >= 10 else 0, 0), 'gyro angle changed by 4 deg during calibration where its '
                                               'drift of 0.00 deg/s explains 0.0 deg'),
], ids=['jolt', 'steady-turn', 'knock'])
def test_a_robot_moved_during_calibration_refuses_to_start(tmp_path, sample, message):
    dev = MemoryDevices()
    calibration_source(dev, sample)
    code, header, path, _ = session(tmp_path, dev)
    h, _ = assert_stopped_and_logged(dev, path, 'calibration', 4, header)
    assert dev.write_calls == 0
    assert message in h['stop_message']


def test_a_drifting_gyro_starts_and_the_old_mode_samples_are_not_used(tmp_path):
    # 3 deg/s of bias drift the angle 3 deg a second; before the mode switch took effect the
    # gyro still reported an angle counted since it was plugged in, and no rate
    dev = MemoryDevices()
    calibration_source(dev, lambda i, used: (int(3 * 0.005 * i) if used else 1800, 3 if used else 0))
    code, header, path, _ = session(tmp_path, dev, duration_s=0.1)
    h, _ = assert_stopped_and_logged(dev, path, 'completed', 0, header)
    cal = h['calibration']
    assert cal['gyro_bias_dps'] == 3.0 and cal['settle_samples'] == 20 and cal['samples'] == 20
    assert abs(cal['unexplained_angle_deg']) < 1


def test_header_has_what_a_replay_needs(tmp_path):
    dev = MemoryDevices(counts_per_rot=(360, 360, 360, 720))
    dev.enc = (123, -45, 6, 7)
    dev.gyro = (4, 2)
    code, header, path, _ = session(tmp_path, dev, duration_s=0.2)
    h, rows = read_log(path)
    assert h['encoder_offsets'] == [123, -45, 6, 7] and h['counts_per_rot'] == [360, 360, 360, 720]
    assert h['calibration']['gyro_bias_dps'] == 2.0
    # x^_0: the start pose at rest and the calibrated bias; row 0 holds it in fixed point
    assert h['estimator'] == 'kalman' and h['x_hat_0'][:12] == [0.0] * 12
    assert h['x_hat_0'][12] == 2.0 * np.pi / 180
    xi0 = rows[0, col_of(h, 'xi_d_r'):col_of(h, 'xi_d_r') + 13]
    np.testing.assert_allclose(xi0, h['x_hat_0'], rtol=0, atol=2.0 ** -30)
    assert h['gains']['sha256'] == 'test-sha' and h['ts_s'] == 0.005
    assert h['config']['limits']['th1_rad'] == 0.6 and 'numpy' in h['versions']
    assert [c['name'] for c in h['columns']][:3] == ['time_s', 'tick_s', 'enc_r']


def test_polarity_changes_only_the_sign_of_what_the_motor_sees(tmp_path):
    # the same physical motion seen through a reversed right-wheel motor: its counts and its
    # duties change sign, the estimate and the applied input u (in the robot's frame) do not
    rows = {}
    for polarity in (1, -1):
        dev = MemoryDevices()
        ticks = TickCounter(dev, lambda n: setattr(dev, 'enc', (polarity * 3 * n, 0, n, 0)))
        config = S.fw_config(polarity={'right_wheel': polarity})
        (tmp_path / str(polarity)).mkdir()
        session(tmp_path / str(polarity), dev, VirtualClock(on_sleep=ticks), duration_s=0.3,
                config=config)
        rows[polarity] = read_log(str(tmp_path / str(polarity) / 'run.log'))[1]
    a, b = rows[1], rows[-1]
    names = [c['name'] for c in read_log(str(tmp_path / '1' / 'run.log'))[0]['columns']]
    for i, c in enumerate(names):
        if c not in ('time_s', 'tick_s', 'enc_r', 'duty_r'):
            np.testing.assert_array_equal(a[:, i], b[:, i], err_msg=c)
    np.testing.assert_array_equal(a[:, names.index('enc_r')], -b[:, names.index('enc_r')])
    np.testing.assert_array_equal(a[:, names.index('duty_r')], -b[:, names.index('duty_r')])
    assert np.abs(a[:, names.index('duty_r')]).max() > 0


class ReadCountingStream(object):
    """A text stream that notes how many device reads had been made at each line written."""

    def __init__(self, dev):
        self.dev, self.lines = dev, []

    def write(self, text):
        self.lines.append((text.strip(), self.dev.raw_reads))

    def flush(self):
        pass


def test_the_owner_is_told_to_hold_then_to_let_go_right_before_the_first_tick(tmp_path):
    dev = MemoryDevices()           # held exactly at the start pose: zero state, no wheel drives
    stream = ReadCountingStream(dev)
    path = str(tmp_path / 'run.log')
    run_session(dev, S.load(), S.fw_config(), VirtualClock(), log_path=path, duration_s=0.1, say=lambda m: None,
                cues=OwnerCues(streams=[stream]))
    settle, n = sample_counts(S.fw_config()['gyro_calibration'], S.load().ts_s)
    assert stream.lines == [('tipbot: HOLD the robot still and upright: calibrating the gyro (0.2 s)', 0),
                            ('tipbot: LET GO NOW: balancing', settle + n),
                            ('tipbot: DONE: ran its duration (exit 0)', settle + n + 20)]
    h, rows = read_log(path)
    assert len(rows) == 20 and not rows[:, col_of(h, 'duty_r'):col_of(h, 'duty_3') + 1].any()   # no wheel ever drove


def test_no_let_go_when_the_calibration_refuses(tmp_path):
    dev = MemoryDevices()
    calibration_source(dev, lambda i, used: (0, 20 * (i % 2)))
    stream = ReadCountingStream(dev)
    code, _ = run_session(dev, S.load(), S.fw_config(), VirtualClock(), say=lambda m: None,
                          cues=OwnerCues(streams=[stream]))
    assert code == 4 and [text for text, _ in stream.lines][1:] == ['tipbot: NOT STARTED: moved while calibrating (exit 4)']
    assert stream.lines[0][0].startswith('tipbot: HOLD')


def test_cues_go_to_stdout_and_stderr_once_each_or_once_for_one_terminal(tmp_path, monkeypatch):
    monkeypatch.delenv('SSH_CONNECTION', raising=False)     # started from brickman
    out, err = open(str(tmp_path / 'out'), 'w'), open(str(tmp_path / 'err'), 'w')
    monkeypatch.setattr('sys.stdout', out)
    monkeypatch.setattr('sys.stderr', err)
    OwnerCues().let_go()
    same = open(str(tmp_path / 'out'), 'a')
    monkeypatch.setattr('sys.stderr', same)
    OwnerCues().let_go()
    for f in (out, err, same):
        f.close()
    assert (tmp_path / 'out').read_text() == 'tipbot: LET GO NOW: balancing\n' * 2
    assert (tmp_path / 'err').read_text() == 'tipbot: LET GO NOW: balancing\n'


@pytest.mark.parametrize('how, words', [('unlink', 'deleted'), ('truncate', 'cut short'),
                                        ('replace', 'replaced'), ('move', 'moved away')])
def test_a_log_taken_away_during_the_run_is_said_at_the_end(tmp_path, how, words):
    """Another process deletes, empties, replaces or moves the log mid-run: the run still stops
    as it would, and its last line says the log is gone instead of naming it as written."""
    path = str(tmp_path / 'run.log')

    def take_away(n):
        if n != 40:
            return
        if how == 'unlink':
            os.unlink(path)
        elif how == 'truncate':
            os.truncate(path, 0)
        elif how == 'replace':
            os.unlink(path)
            open(path, 'wb').close()
        else:
            os.rename(path, path + '.moved')

    dev = MemoryDevices()
    code, header, _, msgs = session(tmp_path, dev, VirtualClock(on_sleep=TickCounter(dev, take_away)), duration_s=0.5)
    assert dev.stop_calls >= 1 and dev.duties == [0, 0, 0, 0]
    assert code == header['exit_code'] == 1     # a completed run whose log is lost is not a success
    assert any(words in m and m.startswith('log {}: '.format(path)) for m in msgs), msgs
    assert msgs[-1] == 'stopped: completed (exit 1, 100 ticks); no log: {} was taken away'.format(path)


def test_a_log_left_alone_is_not_said_to_be_taken_away(tmp_path):
    dev = MemoryDevices()
    code, header, path, msgs = session(tmp_path, dev, duration_s=0.2)
    assert code == 0 and not any('taken away' in m for m in msgs)


def test_over_ssh_without_a_terminal_each_cue_comes_once_and_no_screen_line(tmp_path, monkeypatch):
    """make run from a script: the remote stdout and stderr are two pipes of one ssh session; the
    words come once (on stderr) and the screen's short DONE line not at all."""
    monkeypatch.setenv('SSH_CONNECTION', '10.0.0.2 50000 10.0.0.1 22')
    out, err = open(str(tmp_path / 'out'), 'w'), open(str(tmp_path / 'err'), 'w')
    monkeypatch.setattr('sys.stdout', out)
    monkeypatch.setattr('sys.stderr', err)
    cues = OwnerCues()
    cues.let_go()
    cues.stopped('completed', 0)
    for f in (out, err):
        f.close()
    assert (tmp_path / 'out').read_text() == ''
    assert (tmp_path / 'err').read_text() == 'tipbot: LET GO NOW: balancing\n'
