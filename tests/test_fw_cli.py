"""python3 -m tipbot_fw: refusals before touching devices, exit codes, a run on the fake EV3."""
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

import fw_support as S
from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw import cli
from tipbot_fw.cores.detector_rows import DetectorRows
from tipbot_fw.record.logfile import read_log
from conftest import PHYSICAL_GAINS, REPO



@pytest.fixture
def no_devices(monkeypatch):
    """Fails the test if the CLI tries to open devices."""
    def forbidden(config, root, source):
        raise AssertionError('devices opened')
    monkeypatch.setattr(cli, '_open_devices', forbidden)


def test_invalid_gains_are_refused_before_any_device(tmp_path, capsys, no_devices):
    doc = S.gains_doc()
    doc['K'] = doc['K'][:4]
    path = S.write_json(tmp_path / 'bad.json', doc)
    assert cli.main(['run', '--gains', path]) == 2
    err = capsys.readouterr().err.strip()
    assert err == 'tipbot: refused to start: {}: field K has shape 4x10, expected 5x10'.format(path)


def test_invalid_config_is_refused_before_any_device(tmp_path, capsys, no_devices):
    cfg = S.write_json(tmp_path / 'cfg.json', {'limits': {'th1_rad': -1}})
    assert cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', cfg]) == 2
    err = capsys.readouterr().err
    assert 'refused to start: {}: field limits.th1_rad must be a number in (0, 1.5], got -1'.format(cfg) in err
    assert len(err.strip().splitlines()) == 1


def test_bad_command_line(capsys, no_devices):
    with pytest.raises(SystemExit) as e:
        cli.main(['run', '--gains', PHYSICAL_GAINS, '--duration', '-3'])
    assert e.value.code == 2


@pytest.mark.parametrize('abbreviated', ['--conf', '--sysfs', '--gain'])
def test_an_abbreviated_option_is_refused(abbreviated, capsys, no_devices):
    """The supervisor finds --config and --sysfs-root by their whole names: an abbreviation the
    controller took would give the two another robot's configuration."""
    with pytest.raises(SystemExit) as e:
        cli.main(['run', '--gains', PHYSICAL_GAINS, abbreviated, 'x.json'])
    assert e.value.code == 2 and 'unrecognized arguments: {}'.format(abbreviated) in capsys.readouterr().err


def test_missing_devices(tmp_path, capsys):
    empty = tmp_path / 'sys'
    empty.mkdir()
    assert cli.main(['check', '--sysfs-root', str(empty)]) == 3
    assert 'tipbot: devices: ' in capsys.readouterr().err


def test_a_run_refused_for_missing_devices_writes_a_log_naming_them(tmp_path, capsys):
    with FakeEV3(str(tmp_path / 'sys'), motors={'outC': None}, gyro_port=None) as f:
        log = str(tmp_path / 'run.log')
        assert cli.main(['run', '--gains', PHYSICAL_GAINS, '--log', log, '--sysfs-root', f.sysfs_root]) == 3
    header, rows = read_log(log)
    assert header['stop_reason'] == 'devices' and header['exit_code'] == 3 and len(rows) == 0
    assert 'port outC: no motor found' in header['stop_message'] and 'port in2: no sensor found' in header['stop_message']
    assert '\n' not in header['stop_message'] and header['gains']['path'] == PHYSICAL_GAINS
    assert 'log {}'.format(log) in capsys.readouterr().err


@pytest.mark.parametrize('checkout, where', [(True, 'logs'), (False, '.')])
def test_logs_go_to_logs_in_a_checkout_or_install_directory(tmp_path, monkeypatch, checkout, where):
    from tipbot_fw.record import logfile
    if checkout:
        (tmp_path / 'tipbot_fw').mkdir()
    monkeypatch.chdir(tmp_path)
    path = logfile.default_path('tipbot')
    assert os.path.dirname(path) == ('logs' if checkout else '') and os.path.isdir(where)
    assert os.path.basename(path).startswith('tipbot-2') and path.endswith('.log')


@pytest.fixture
def fake(tmp_path):
    f = FakeEV3(str(tmp_path / 'sys'), battery_v=8.2)
    # nothing polls the fake during these runs, so the gyro stays in its first mode (its
    # bin_data then reads as angle 0, rate 0); the encoders are read as they are set
    f.set_readings((100, -20, 30, 40))
    yield f
    f.close()


@pytest.fixture
def quick_config(tmp_path):
    return S.write_json(tmp_path / 'quick.json',
                        {'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})


def test_run_on_the_fake_ev3(fake, tmp_path, quick_config, capsys):
    log = str(tmp_path / 'run.log')
    code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', quick_config, '--duration', '0.1',
                     '--log', log, '--sysfs-root', fake.sysfs_root])
    out, err = capsys.readouterr()
    assert code == 0, err
    # when to let go, though the state is zero and no wheel drives: on the brick's screen
    # (stdout) and over ssh (stderr)
    for text in (out, err):
        assert 'tipbot: HOLD the robot still and upright: calibrating the gyro (0.1 s)\n' \
               'tipbot: LET GO NOW: balancing\n' in text
    header, rows = read_log(log)
    assert header['stop_reason'] == 'completed' and len(rows) == 20
    assert header['encoder_offsets'] == [100, -20, 30, 40]
    assert header['counts_per_rot'] == [360, 360, 360, 360]
    assert np.all(rows[:, DetectorRows.col('battery_v')] == pytest.approx(8.2))
    states = fake.poll()
    for port in ('outA', 'outB', 'outC', 'outD'):
        assert fake.motor_duty(port) == 0 and not fake.motor_running(port), states[port]


def test_an_old_config_with_the_overruns_in_a_row_still_runs_with_a_note(fake, tmp_path, capsys):
    old = S.write_json(tmp_path / 'old.json', {'realtime_priority': 0, 'limits': {'max_consecutive_overruns': 5},
                                               'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})
    assert cli.main(['check', '--config', old, '--sysfs-root', fake.sysfs_root]) == 0
    _, err = capsys.readouterr()
    assert 'tipbot: {}: field limits.max_consecutive_overruns is no longer used'.format(old) in err
    assert 'Traceback' not in err


def test_check_and_calibrate_on_the_fake_ev3(fake, quick_config, capsys):
    assert cli.main(['check', '--config', quick_config, '--sysfs-root', fake.sysfs_root]) == 0
    out = capsys.readouterr().out
    assert 'encoders [100, -20, 30, 40] counts' in out
    assert 'battery 8.20 V' in out and 'gyro bias 0.000 deg/s' in out
    fake.set_battery_v(6.0)
    assert cli.main(['check', '--config', quick_config, '--sysfs-root', fake.sysfs_root]) == 4
    assert cli.main(['calibrate', '--config', quick_config, '--sysfs-root', fake.sysfs_root]) == 0
    assert 'gyro bias 0.000 deg/s' in capsys.readouterr().out


def test_bench_imports_only_the_firmware_and_numpy():
    code = ("import sys; from tipbot_fw import bench; rc = bench.main(['--ticks', '300']); "
            "bad = [m for m in ('ev3dev2', 'scipy', 'hostsim', 'tipbot_fw.io.ev3dev') if m in sys.modules]; "
            "print(rc, bad)")
    out = subprocess.run([sys.executable, '-c', code], cwd=REPO, stdout=subprocess.PIPE,
                         universal_newlines=True, check=True).stdout
    assert out.splitlines()[-1] == '0 []'
    assert 'ticks 300 (+1 start tick)' in out


def test_module_entry_point_runs():
    p = subprocess.run([sys.executable, '-m', 'tipbot_fw', '--help'], cwd=REPO,
                       stdout=subprocess.PIPE, universal_newlines=True)
    assert p.returncode == 0 and '143 terminated by a signal (SIGTERM' in p.stdout


# numpy's C extension imports turn a KeyboardInterrupt raised inside them into an ImportError
# (seen in CI: "PyCapsule_Import could not import module datetime"); this stand-in does the same
INTERRUPTED_NUMPY = """
import os, signal, time
try:
    os.kill(os.getpid(), signal.{})
    time.sleep(5)
except BaseException:
    raise ImportError('PyCapsule_Import could not import module "datetime"')
"""


@pytest.mark.parametrize('sig, status, words', [('SIGINT', 130, 'interrupted'),
                                                ('SIGTERM', 143, 'terminated by SIGTERM')])
def test_a_signal_inside_numpys_import_is_one_line_not_a_traceback(tmp_path, sig, status, words):
    (tmp_path / 'numpy').mkdir()
    (tmp_path / 'numpy' / '__init__.py').write_text(INTERRUPTED_NUMPY.format(sig))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), REPO]))
    p = subprocess.run([sys.executable, '-m', 'tipbot_fw', 'run', '--gains', PHYSICAL_GAINS],
                       cwd=REPO, env=env, stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    assert p.returncode == status and 'Traceback' not in p.stderr, p.stderr
    assert p.stderr.strip() == 'tipbot: {} while starting: nothing was started'.format(words)


def test_an_import_error_without_a_signal_is_not_called_an_interrupt(tmp_path):
    (tmp_path / 'numpy').mkdir()
    (tmp_path / 'numpy' / '__init__.py').write_text('raise ImportError("numpy is broken here")\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), REPO]))
    p = subprocess.run([sys.executable, '-m', 'tipbot_fw', 'run', '--gains', PHYSICAL_GAINS],
                       cwd=REPO, env=env, stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    assert p.returncode == 1 and 'numpy is broken here' in p.stderr and 'interrupted' not in p.stderr


def test_on_robot_bench_runs_against_any_devices():
    from tipbot_fw.bench import brick_bench
    from tipbot_fw.io.devices import MemoryDevices
    dev = MemoryDevices()
    lines = []
    brick_bench(dev, S.load(), S.fw_config(), 40, say=lines.append)
    assert [line.split(':')[0].strip() for line in lines] == [
        'read_raw (5 reads)', 'write_duties (4 writes)', 'core step (compute)',
        'loop tick (read..write)', 'overruns', 'a tick', 'verdict']
    assert 'of the 5 ms period' in lines[5] and 'this brick keeps 5 ms' in lines[6]
    assert dev.duties == [0, 0, 0, 0] and dev.stop_calls >= 2
    assert dev.duty_writes >= 40 * 4      # the pattern, not the controller, was written


def _sigterm_self(*_):
    os.kill(os.getpid(), signal.SIGTERM)


@pytest.mark.parametrize('where', ['while the log file is made', 'right after the log is opened',
                                   'right after the running line'])
def test_a_signal_in_the_start_window_leaves_a_log_that_reads(fake, tmp_path, quick_config, capsys,
                                                              monkeypatch, where):
    """SIGTERM before the session's guard takes over (the adversary's 'right after running ...')
    ends with a readable log that says why, and the motors stopped; never a half-made file."""
    from tipbot_fw.record import container
    if where == 'while the log file is made':
        real = container.LogWriter._write
        def write(self, data, at=None):
            _sigterm_self()
            return real(self, data, at)
        monkeypatch.setattr(container.LogWriter, '_write', write)
    elif where == 'right after the log is opened':
        real_open = cli.open_log
        monkeypatch.setattr(cli, 'open_log', lambda *a: (real_open(*a), _sigterm_self())[0])
    else:
        real_say = cli._say
        monkeypatch.setattr(cli, '_say', lambda m: (real_say(m), m.startswith('running') and _sigterm_self()))
    log = str(tmp_path / 'run.log')
    code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', quick_config, '--duration', '5',
                     '--log', log, '--sysfs-root', fake.sysfs_root])
    err = capsys.readouterr().err
    assert code == 143, err
    header, rows = read_log(log)
    assert header['stop_reason'] == 'sigterm' and header['exit_code'] == 143 and len(rows) == 0
    assert 'nothing ran' not in err and 'log {}'.format(log) in err and 'Traceback' not in err
    for port in ('outA', 'outB', 'outC', 'outD'):
        assert fake.motor_duty(port) == 0 and not fake.motor_running(port)


@pytest.mark.parametrize('fields, expected', [
    ({'drivers': {'joint3': 'lego-ev3-l-motor'}},
     ['field drivers.joint3: port outD: expected lego-ev3-l-motor, found lego-ev3-m-motor']),
    ({'ports': {'gyro': 'in1'}}, ['field ports.gyro: port in1: no sensor found (expected lego-ev3-gyro)']),
    ({'drivers': {'joint3': 'lego-ev3-l-motor'}, 'ports': {'gyro': 'in1'}},
     ['field drivers.joint3: port outD', 'field ports.gyro: port in1']),
])
def test_a_config_naming_a_wrong_device_is_refused_by_file_and_field(tmp_path, capsys, fields, expected):
    """The adversary's config with the wrong driver or port: one line naming the file and field."""
    cfg = S.write_json(tmp_path / 'config.json', fields)
    with FakeEV3(str(tmp_path / 'sys')) as f:
        assert cli.main(['check', '--config', cfg, '--sysfs-root', f.sysfs_root]) == 3
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    assert err.startswith('tipbot: devices: {}: field '.format(cfg))
    for part in expected:
        assert '{}: {}'.format(cfg, part) in err


def test_every_option_of_every_command_has_a_help_text():
    import argparse
    parser = cli._parser(["--help"])     # the full parser: every command's options
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = ['{} {}'.format(name, a.option_strings[0]) for name, sp in subs.choices.items()
               for a in sp._actions if a.option_strings and a.help in (None, '')]
    assert missing == []
