"""tipbot_fw.io.ev3dev.Ev3Devices against hostsim.world.fake_ev3: start-up checks and set-up, the per-tick
I/O budget (5 reads, <= 4 writes), what the fake sees, failures, and a cross-process run."""
import ast
import copy
import errno
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw import config as fw_config
from tipbot_fw.io.ev3dev import (Ev3Devices, Ev3ReadError, Ev3SetupError, Ev3WriteError)
from conftest import REPO

PORTS = ('outA', 'outB', 'outC', 'outD')
EV3IO_PATH = os.path.join(REPO, 'tipbot_fw', 'io', 'ev3dev.py')


@pytest.fixture
def config():
    return fw_config.defaults()


@pytest.fixture
def devs(fake, config):
    d = Ev3Devices(config, fake.sysfs_root, io=fake.io)
    fake.poll()
    fake.io.reset()
    yield d
    d.close()


def write_attr(fake, port, name, data):
    fd = os.open(fake.attribute_path(port, name), os.O_WRONLY)
    try:
        os.pwrite(fd, data, 0)
    finally:
        os.close(fd)


# ---------------------------------------------------------------- start-up
def test_start_up_puts_every_motor_in_run_direct_at_duty_0_and_the_gyro_in_g_and_a(fake, config):
    # Leftovers of another program: sysfs polarity inversed, a duty, a different stop action.
    write_attr(fake, 'outB', 'polarity', b'inversed\n')
    write_attr(fake, 'outB', 'duty_cycle_sp', b'60\n')
    write_attr(fake, 'outB', 'stop_action', b'hold\n')
    write_attr(fake, 'outB', 'command', b'run-direct\n')
    assert fake.poll()['outB'].duty == -60
    cfg = copy.deepcopy(config)
    cfg['stop_action'] = 'brake'
    with Ev3Devices(cfg, fake.sysfs_root, io=fake.io) as d:
        states = fake.poll()
        for port in PORTS:
            s = states[port]
            assert (s.command, s.running, s.duty, s.polarity, s.stop_action) == (
                'run-direct', True, 0, 'normal', 'brake'), port
        assert fake.gyro_mode == 'GYRO-G&A'
        assert d.counts_per_rot == (360, 360, 360, 360)
        assert d.paths['outD'] == fake.device_path('outD')
        assert d.paths['in2'] == fake.device_path('in2')
        assert fake.errors == []


def test_stop_action_defaults_to_coast(devs, fake):
    assert all(s.stop_action == 'coast' for s in fake.poll().values())


@pytest.mark.parametrize('kwargs, problems', [
    (dict(gyro_port=None), ['port in2: no sensor found (expected lego-ev3-gyro)']),
    (dict(gyro_port='in3'), ['port in2: no sensor found (expected lego-ev3-gyro)']),
    (dict(gyro_driver='lego-ev3-touch'), ['port in2: expected lego-ev3-gyro, found lego-ev3-touch']),
    (dict(motors={'outD': 'lego-ev3-l-motor'}),
     ['port outD: expected lego-ev3-m-motor, found lego-ev3-l-motor']),
    (dict(motors={'outC': None}), ['port outC: no motor found (expected lego-ev3-l-motor)']),
    (dict(motors={'outA': None, 'outD': 'lego-ev3-l-motor'}, gyro_port=None),
     ['port outA: no motor found (expected lego-ev3-l-motor)',
      'port outD: expected lego-ev3-m-motor, found lego-ev3-l-motor',
      'port in2: no sensor found (expected lego-ev3-gyro)']),
])
def test_start_up_names_every_missing_or_wrong_device_and_touches_nothing(kwargs, problems, config):
    with FakeEV3(**kwargs) as f:
        with pytest.raises(Ev3SetupError) as e:
            Ev3Devices(config, f.sysfs_root, io=f.io)
        assert e.value.problems == problems
        for p in problems:
            assert p in str(e.value)
        assert f.io.writes == 0 and f.io.open_fds == {}
        assert not any(s.running for s in f.poll().values())


def test_start_up_on_an_empty_tree_lists_all_five_devices(tmp_path, config):
    with pytest.raises(Ev3SetupError) as e:
        Ev3Devices(config, str(tmp_path))
    assert len(e.value.problems) == 5
    assert e.value.problems[0] == 'port outA: no motor found (expected lego-ev3-l-motor)'


def test_start_up_accepts_full_port_names_in_the_config(fake, config):
    cfg = copy.deepcopy(config)
    cfg['ports']['gyro'] = 'ev3-ports:in2'
    with Ev3Devices(cfg, fake.sysfs_root) as d:
        assert d.read_raw()[1] == (0, 0)


@pytest.mark.parametrize('port, name, message', [
    ('outB', 'position', 'port outB: cannot open position'),
    ('outD', 'command', 'port outD: cannot open command'),
    ('in2', 'bin_data', 'port in2: cannot open bin_data'),
    ('battery', 'voltage_now', 'port battery: cannot open power_supply/lego-ev3-battery/voltage_now'),
])
def test_start_up_names_a_missing_attribute_and_closes_what_it_opened(port, name, message, fake, config):
    fake.remove_attribute(port, name)
    with pytest.raises(Ev3SetupError, match=message):
        Ev3Devices(config, fake.sysfs_root, io=fake.io)
    assert fake.io.open_fds == {}
    assert fake.io.writes == 0


def test_a_failed_set_up_stops_the_motors_it_started(fake, config):
    fake.io.fail(fake.relpath('in2', 'mode'), 'pwrite', errno.EIO)
    with pytest.raises(Ev3SetupError, match="port in2: writing mode 'GYRO-G&A' failed"):
        Ev3Devices(config, fake.sysfs_root, io=fake.io)
    states = fake.poll()
    assert all(not s.running and s.duty == 0 and s.command == 'stop' for s in states.values())
    assert fake.io.open_fds == {}


def test_config_without_ports_is_refused():
    with pytest.raises(Ev3SetupError, match='config: missing field ports.right_wheel'):
        Ev3Devices({'drivers': {}}, '/nonexistent')


# ---------------------------------------------------------------- the tick
def test_read_raw_returns_the_raw_counts_and_gyro_values_the_fake_holds(devs, fake):
    fake.set_readings((1234567, -8, 90, -45), (-17, 250))
    assert devs.read_raw() == ((1234567, -8, 90, -45), (-17, 250))
    fake.set_readings((0, 1, 2, 3), (32767, -440))
    assert devs.read_raw() == ((0, 1, 2, 3), (32767, -440))
    assert fake.io.reads == 10 and fake.io.writes == 0


def test_counts_follow_the_sysfs_position_which_start_up_made_normal(devs, fake):
    # a client flipping the sysfs polarity later negates what the driver reports; Ev3Devices
    # passes it on untouched (polarity is the signal chain's)
    fake.set_encoder_counts('outA', 40)
    write_attr(fake, 'outA', 'polarity', b'inversed\n')
    fake.poll()
    assert devs.read_raw()[0][0] == -40


def test_write_duties_writes_only_changed_duties_and_the_fake_applies_them(devs, fake):
    io = fake.io
    sequence = [((100, 0, 0, 0), 1), ((5, 0, 0, 0), 1), ((-3, 0, 0, 0), 1),
                ((-3, 0, 0, 0), 0), ((-3, 100, -100, 7), 3), ((0, 0, 0, 0), 4)]
    for duties, writes in sequence:
        io.reset()
        devs.write_duties(duties)
        assert io.writes == writes, duties
        states = fake.poll()
        assert tuple(states[p].duty for p in PORTS) == duties
        assert tuple(int(open(fake.attribute_path(p, 'duty_cycle'), 'rb').read()) for p in PORTS) == duties
    assert io.writes_to('motor0/duty_cycle_sp') == [b'0\n']
    assert fake.errors == []


def test_one_control_tick_is_5_reads_and_at_most_4_writes(devs, fake):
    rng = np.random.default_rng(42)
    io = fake.io
    applied = (0, 0, 0, 0)
    for _ in range(200):
        fake.set_readings(tuple(int(c) for c in rng.integers(-5000, 5000, 4)),
                          tuple(int(g) for g in rng.integers(-440, 440, 2)))
        # duties that often repeat, as a saturated or resting controller's do
        duties = tuple(int(d) for d in rng.choice([-100, -7, 0, 3, 100], 4))
        io.reset()
        devs.read_raw()
        devs.write_duties(duties)
        assert io.reads == 5
        assert io.writes == sum(a != b for a, b in zip(duties, applied)) <= 4
        assert all(op == 'pwrite' and rel.endswith('duty_cycle_sp')
                   for op, rel, _ in io.log if op == 'pwrite')
        states = fake.poll()
        applied = tuple(states[p].duty for p in PORTS)
        assert applied == duties


@pytest.mark.parametrize('bad', [101, -101, 2.5, None])
def test_a_duty_out_of_range_is_refused_without_writing(devs, fake, bad):
    with pytest.raises(ValueError, match=r'port outC: duty .* is not an integer in \[-100, 100\]'):
        devs.write_duties((10, 20, bad, 30))
    states = fake.poll()
    assert (states['outA'].duty, states['outB'].duty, states['outC'].duty) == (10, 20, 0)


def test_a_failed_duty_write_names_the_port_and_is_retried(devs, fake):
    rel = fake.relpath('outB', 'duty_cycle_sp')
    fake.io.fail(rel, 'pwrite', errno.ENODEV)
    with pytest.raises(Ev3WriteError) as e:
        devs.write_duties((10, 20, 30, 40))
    assert isinstance(e.value, OSError) and e.value.errno == errno.ENODEV
    assert str(e.value).startswith('port outB: writing duty_cycle_sp failed: ')
    fake.io.clear_failures()
    fake.io.reset()
    devs.write_duties((10, 20, 30, 40))
    assert fake.io.writes == 3          # outA was written before the failure
    assert tuple(fake.poll()[p].duty for p in PORTS) == (10, 20, 30, 40)


@pytest.mark.parametrize('port, name', [('outA', 'position'), ('outC', 'position'), ('in2', 'bin_data')])
def test_a_read_failure_names_the_port_and_attribute(devs, fake, port, name):
    fake.io.fail(fake.relpath(port, name), 'pread', errno.ENODEV)
    with pytest.raises(Ev3ReadError) as e:
        devs.read_raw()
    assert isinstance(e.value, OSError)          # what tipbot_fw.loop treats as a device failure
    assert e.value.errno == errno.ENODEV
    assert (e.value.port, e.value.attribute) == (port, name)
    assert str(e.value).startswith('port {}: reading {} failed: '.format(port, name))


@pytest.mark.parametrize('port, name', [('outD', 'position'), ('in2', 'bin_data')])
def test_an_empty_or_garbled_read_is_a_read_error_too(devs, fake, port, name):
    os.truncate(fake.attribute_path(port, name), 0)
    with pytest.raises(Ev3ReadError, match='port {}: reading {} failed'.format(port, name)):
        devs.read_raw()


def test_read_battery_v(devs, fake):
    assert devs.read_battery_v() == pytest.approx(8.0)
    fake.set_battery_v(6.95)
    assert devs.read_battery_v() == pytest.approx(6.95)
    fake.io.fail(fake.relpath('battery', 'voltage_now'))
    with pytest.raises(Ev3ReadError, match='port battery: reading voltage_now failed'):
        devs.read_battery_v()


# ---------------------------------------------------------------- stopping
def test_stop_all_stops_every_motor_with_duty_0(devs, fake):
    devs.write_duties((50, -50, 20, -20))
    assert all(s.running for s in fake.poll().values())
    assert devs.stop_all() == []
    states = fake.poll()
    assert all(s.duty == 0 and not s.running and s.command == 'stop' for s in states.values())
    assert fake.io.writes_to('duty_cycle_sp')[-4:] == [b'0\n'] * 4
    assert devs.stop_all() == []                         # idempotent
    assert all(s.duty == 0 and not s.running for s in fake.poll().values())


def test_stop_all_goes_on_when_one_motors_files_fail(devs, fake):
    devs.write_duties((50, -50, 20, -20))
    fake.poll()
    fake.io.fail(fake.relpath('outB', 'duty_cycle_sp'), 'pwrite', errno.EIO)
    fake.io.fail(fake.relpath('outC', 'command'), 'pwrite', errno.EIO)
    failures = devs.stop_all()
    assert len(failures) == 2
    assert failures[0].startswith('port outB: writing duty_cycle_sp during stop_all failed')
    assert failures[1].startswith('port outC: writing command during stop_all failed')
    states = fake.poll()
    assert all(s.duty == 0 for s in states.values())    # B by its stop command, C by its duty
    assert [p for p in PORTS if states[p].running] == ['outC']


def test_stop_all_never_raises_even_if_everything_fails(devs, fake):
    for p in PORTS:
        fake.io.fail(fake.relpath(p, 'duty_cycle_sp'), 'pwrite')
        fake.io.fail(fake.relpath(p, 'command'), 'pwrite')
    assert len(devs.stop_all()) == 8


def test_write_duties_after_stop_all_does_not_restart_the_motors(devs, fake):
    devs.stop_all()
    devs.write_duties((30, 30, 30, 30))
    assert all(s.duty == 0 and not s.running for s in fake.poll().values())


def test_close_stops_the_motors_and_closes_every_descriptor(fake, config):
    d = Ev3Devices(config, fake.sysfs_root, io=fake.io)
    d.write_duties((40, 40, 40, 40))
    assert len(fake.io.open_fds) == 14   # 4 x (position, duty_cycle_sp, command), bin_data, battery
    d.close()
    assert fake.io.open_fds == {}
    assert all(s.duty == 0 and not s.running for s in fake.poll().values())
    d.close()
    assert d.stop_all() == []


# ---------------------------------------------------------------- across processes
WRITER = textwrap.dedent('''
    import os, sys
    from hostsim.world.fake_ev3 import FakeEV3
    root, stop_file = sys.argv[1], sys.argv[2]
    COUNTS = (-1234567, 8, 99999, -5, 0, 7654321, 42, -100000)
    ANGLES = (1, -300, 32000, -32000, 255, -256, 0, 77)
    fake = FakeEV3(root_dir=root)
    fd = os.open(fake.attribute_path('in2', 'mode'), os.O_WRONLY)
    os.pwrite(fd, b'GYRO-G&A\\n', 0)
    os.close(fd)
    fake.poll()
    for i in range(5000000):
        k = i % 8
        for j, port in enumerate(fake.motor_ports):
            fake.set_encoder_counts(port, COUNTS[(k + j) % 8])
        fake.set_gyro(ANGLES[k], -ANGLES[k])
        fake.poll()
        if i == 100:
            print('ready', flush=True)
        if i % 64 == 0 and os.path.exists(stop_file):
            break
    print(i, flush=True)
    fake.close()
''')
COUNTS = {-1234567, 8, 99999, -5, 0, 7654321, 42, -100000}
ANGLES = {1, -300, 32000, -32000, 255, -256, 0, 77}


def test_values_written_by_another_process_are_never_read_torn(tmp_path, config):
    root = str(tmp_path / 'sys-class')
    stop_file = str(tmp_path / 'stop')
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get('PYTHONPATH', ''))
    writer = subprocess.Popen([sys.executable, '-c', WRITER, root, stop_file], cwd=REPO, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    try:
        assert writer.stdout.readline().strip() == 'ready', writer.stderr.read()
        devs = Ev3Devices(config, root)          # the real os calls on the files
        bad = []
        seen = set()
        reads = 0
        while reads < 400000 and (reads < 20000 or len(seen) < 8):
            counts, (angle, rate) = devs.read_raw()
            reads += 1
            if not COUNTS.issuperset(counts) or angle not in ANGLES or rate != -angle:
                bad.append((counts, angle, rate))
            seen.add(angle)
        devs.close()
    finally:
        open(stop_file, 'w').close()
        out, err = writer.communicate(timeout=60)
    assert writer.returncode == 0, err
    assert bad == []
    assert len(seen) >= 2, 'the writer never changed the values while we read: no overlap tested'
    assert int(out.split()[-1]) > 100


# ---------------------------------------------------------------- robot-side constraints
# (Python 3.5 syntax and modules: tests/test_py35_compat.py runs vermin over all of tipbot_fw/, ev3io.py included)
def test_ev3io_imports_only_what_the_brick_has():
    tree = ast.parse(open(EV3IO_PATH).read())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split('.')[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            names.add(node.module.split('.')[0])
    assert names <= {'os', 'struct', 'ev3dev2', 'tipbot_fw'}, names

