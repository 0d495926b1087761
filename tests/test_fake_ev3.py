"""hostsim.world.fake_ev3: layout and formats, python-ev3dev2 accepts the tree unchanged, client
writes of any length are seen, failure injection, and the sensor models feeding it."""
import errno
import os
import struct

import numpy as np
import pytest

import ev3dev2
from ev3dev2 import DeviceNotFound
from ev3dev2.motor import OUTPUT_A, OUTPUT_B, OUTPUT_D, LargeMotor, MediumMotor
from ev3dev2.power import PowerSupply
from ev3dev2.sensor import INPUT_2
from ev3dev2.sensor.lego import GyroSensor

from hostsim.world import fake_ev3
from hostsim.world.fake_ev3 import CountingIO, FakeEV3, file_mode, parse_choice
from hostsim.world.sensors import SensorModel


@pytest.fixture
def ev3dev2_root(fake):
    saved = ev3dev2.Device.DEVICE_ROOT_PATH
    ev3dev2.Device.DEVICE_ROOT_PATH = fake.sysfs_root
    yield fake
    ev3dev2.Device.DEVICE_ROOT_PATH = saved


def read(fake, port, name):
    with open(fake.attribute_path(port, name), 'rb') as f:
        return f.read()


# ---------------------------------------------------------------- layout and formats
def test_layout_permissions_and_formats(fake):
    root = fake.sysfs_root
    assert sorted(os.listdir(root + '/tacho-motor')) == ['motor0', 'motor1', 'motor2', 'motor3']
    assert read(fake, 'outA', 'address').strip() == b'ev3-ports:outA'
    assert read(fake, 'outD', 'driver_name').strip() == b'lego-ev3-m-motor'
    assert read(fake, 'outA', 'count_per_rot').strip() == b'360'
    assert read(fake, 'outA', 'commands').split() == [c.encode() for c in fake_ev3.MOTOR_COMMANDS]
    # sysfs permissions, as python-ev3dev2 uses them to pick 'r', 'r+' or 'w'
    assert file_mode(fake.attribute_path('outA', 'command')) == 0o220
    assert file_mode(fake.attribute_path('outA', 'duty_cycle_sp')) == 0o664
    assert file_mode(fake.attribute_path('outA', 'position')) == 0o444
    assert read(fake, 'in2', 'address').strip() == b'ev3-ports:in2'
    assert read(fake, 'in2', 'driver_name').strip() == b'lego-ev3-gyro'
    assert read(fake, 'in2', 'bin_data_format').strip() == b's16'
    assert len(read(fake, 'in2', 'bin_data')) == fake_ev3.BIN_DATA_BYTES
    assert read(fake, 'battery', 'voltage_now').strip() == b'8000000'
    with open(root + '/board-info/board0/uevent') as f:
        assert 'BOARD_INFO_MODEL=LEGO MINDSTORMS EV3' in f.read().splitlines()


def test_fake_records_keep_their_size_when_values_shrink(fake):
    fake.set_encoder_counts('outB', -1234567)
    big = read(fake, 'outB', 'position')
    fake.set_encoder_counts('outB', 5)
    small = read(fake, 'outB', 'position')
    assert len(big) == len(small) == fake_ev3.RECORD_BYTES
    assert int(big) == -1234567 and int(small) == 5


def test_gyro_bin_data_is_two_little_endian_s16_in_g_and_a_mode(fake):
    write_attr(fake, 'in2', 'mode', b'GYRO-G&A\n')
    fake.set_gyro(0, 0)
    fake.poll()
    fake.set_gyro(-300, 123)
    raw = read(fake, 'in2', 'bin_data')
    assert struct.unpack('<hh', raw[:4]) == (-300, 123)
    assert raw[4:] == b'\0' * (fake_ev3.BIN_DATA_BYTES - 4)
    assert read(fake, 'in2', 'num_values').strip() == b'2'
    assert int(read(fake, 'in2', 'value0')) == -300 and int(read(fake, 'in2', 'value1')) == 123


def test_vocabularies_are_prefix_free_and_parse_overlaid_writes():
    for vocab in (fake_ev3.MOTOR_COMMANDS, fake_ev3.STOP_ACTIONS, fake_ev3.POLARITIES,
                  fake_ev3.GYRO_MODE_NAMES):
        for a in vocab:
            assert [b for b in vocab if b.startswith(a)] == [a]
    assert parse_choice(b'normaled\n', fake_ev3.POLARITIES) == 'normal'
    assert parse_choice(b'stop\ndirect\n', fake_ev3.MOTOR_COMMANDS) == 'stop'
    assert parse_choice(b'stopdirect', fake_ev3.MOTOR_COMMANDS) == 'stop'
    assert parse_choice(b'GYRO-ANGE', fake_ev3.GYRO_MODE_NAMES) == 'GYRO-ANG'
    assert parse_choice(b'bogus\n', fake_ev3.POLARITIES) is None


# ---------------------------------------------------------------- python-ev3dev2 unchanged
def test_ev3dev2_finds_motors_by_address_and_reads_them(ev3dev2_root):
    fake = ev3dev2_root
    fake.set_encoder_counts('outA', 4321)
    fake.set_encoder_counts('outD', -17)
    a = LargeMotor(OUTPUT_A)
    assert a.address == 'ev3-ports:outA'
    assert a.driver_name == 'lego-ev3-l-motor'
    assert a.position == 4321
    assert a.count_per_rot == 360 and a.max_speed == 1050
    assert a.state == [] and a.polarity == 'normal'
    d = MediumMotor(OUTPUT_D)
    assert d.position == -17 and d.max_speed == 1560
    fake.set_encoder_counts('outA', -5)     # every read is the current value
    assert a.position == -5
    with pytest.raises(DeviceNotFound):
        LargeMotor(OUTPUT_D)                # wrong driver on D
    with pytest.raises(DeviceNotFound):
        MediumMotor(OUTPUT_B)


def test_ev3dev2_gyro_angle_rate_and_mode_switches(ev3dev2_root):
    fake = ev3dev2_root
    fake.set_gyro(12, -3)
    g = GyroSensor(INPUT_2)                 # reads .angle; the fake starts in GYRO-ANG
    assert g.angle == 12
    assert g.mode == 'GYRO-ANG'
    g.mode = 'GYRO-RATE'                    # longer value over a shorter one
    fake.poll()
    assert fake.gyro_mode == 'GYRO-RATE'
    assert g.units == 'd/s'
    assert g.rate == -3
    g.mode = 'GYRO-G&A'                     # shorter over longer: stale 'E' left in the file
    fake.poll()
    assert fake.gyro_mode == 'GYRO-G&A'
    fake.set_gyro(20, 7)                    # the angle restarted at 12 when G&A was entered
    assert g.num_values == 2
    assert g.value(0) == 8 and g.value(1) == 7
    assert tuple(g.bin_data('<hh')) == (8, 7)
    g.mode = 'GYRO-ANG'
    fake.poll()
    assert fake.gyro_mode == 'GYRO-ANG' and g.value(0) == 0


def test_ev3dev2_power_supply(ev3dev2_root):
    fake = ev3dev2_root
    p = PowerSupply()
    assert p.measured_volts == pytest.approx(8.0)
    fake.set_battery_v(7.25)
    assert p.measured_volts == pytest.approx(7.25)
    assert p.measured_voltage == 7250000


def test_ev3dev2_shorter_writes_are_seen(ev3dev2_root):
    fake = ev3dev2_root
    m = LargeMotor(OUTPUT_A)
    m.polarity = 'inversed'
    m.stop_action = 'brake'
    fake.poll()
    assert fake.motor_state('outA').polarity == 'inversed'
    assert fake.motor_state('outA').stop_action == 'brake'
    m.polarity = 'normal'                   # file now reads 'normaled'
    m.stop_action = 'hold'                  # file now reads 'holde'
    fake.poll()
    assert fake.motor_state('outA').polarity == 'normal'
    assert fake.motor_state('outA').stop_action == 'hold'
    m.run_direct()                          # command is write-only: ev3dev2 opens it 'w'
    fake.poll()
    assert fake.motor_running('outA') and fake.motor_state('outA').command == 'run-direct'
    m.stop()                                # 'stop' over 'run-direct'
    fake.poll()
    assert not fake.motor_running('outA')
    assert fake.motor_state('outA').command == 'stop'
    assert fake.poll()['outA'].duty == 0
    assert fake.errors == []


def test_ev3dev2_reset_zeroes_position(ev3dev2_root):
    fake = ev3dev2_root
    fake.set_encoder_counts('outB', 500)
    m = LargeMotor(OUTPUT_B)
    m.reset()
    fake.poll()
    assert m.position == 0
    fake.set_encoder_counts('outB', 530)
    assert m.position == 30


# ---------------------------------------------------------------- motor semantics
def write_attr(fake, port, name, data):
    fd = os.open(fake.attribute_path(port, name), os.O_WRONLY)
    try:
        os.pwrite(fd, data, 0)
    finally:
        os.close(fd)


def test_duty_applies_only_while_running_direct_and_shorter_values_replace_longer(fake):
    write_attr(fake, 'outC', 'duty_cycle_sp', b'100\n')
    assert fake.poll()['outC'].duty == 0     # not running yet
    write_attr(fake, 'outC', 'command', b'run-direct\n')
    assert fake.poll()['outC'].duty == 100
    for data, duty in ((b'5\n', 5), (b'-3\n', -3), (b'-100\n', -100), (b'0\n', 0)):
        write_attr(fake, 'outC', 'duty_cycle_sp', data)
        assert fake.poll()['outC'].duty == duty
        assert int(read(fake, 'outC', 'duty_cycle')) == duty
    assert read(fake, 'outC', 'state').strip() == b'running'
    write_attr(fake, 'outC', 'command', b'stop\n')
    state = fake.poll()['outC']
    assert state == fake_ev3.MotorState(0, False, 'stop', 0, 'normal', 'coast')
    assert read(fake, 'outC', 'state').strip() == b''
    assert fake.errors == []


def test_sysfs_polarity_inversed_negates_position_and_duty(fake):
    fake.set_encoder_counts('outA', 40)
    write_attr(fake, 'outA', 'polarity', b'inversed\n')
    write_attr(fake, 'outA', 'duty_cycle_sp', b'30\n')
    write_attr(fake, 'outA', 'command', b'run-direct\n')
    assert fake.poll()['outA'].duty == -30
    assert int(read(fake, 'outA', 'position')) == -40


def test_out_of_range_or_garbled_writes_are_rejected_like_einval(fake):
    write_attr(fake, 'outA', 'command', b'run-direct\n')
    write_attr(fake, 'outA', 'duty_cycle_sp', b'50\n')
    fake.poll()
    write_attr(fake, 'outA', 'duty_cycle_sp', b'150\n')
    write_attr(fake, 'outA', 'polarity', b'upside-down\n')
    assert fake.poll()['outA'].duty == 50
    assert len(fake.errors) == 2
    assert 'port outA duty_cycle_sp: out of range' in fake.errors[0]
    assert 'port outA polarity: not one of normal inversed' in fake.errors[1]


def test_repeated_identical_command_is_seen_by_mtime(fake):
    fake.set_encoder_counts('outA', 100)
    write_attr(fake, 'outA', 'command', b'reset\n')
    fake.poll()
    assert int(read(fake, 'outA', 'position')) == 0
    fake.set_encoder_counts('outA', 150)
    path = fake.attribute_path('outA', 'command')
    st = os.stat(path)
    write_attr(fake, 'outA', 'command', b'reset\n')
    # the same bytes again: only the mtime tells; make sure it moves whatever the clock grain
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1000))
    fake.poll()
    assert int(read(fake, 'outA', 'position')) == 0


def test_missing_and_wrong_devices():
    with FakeEV3(motors={'outD': 'lego-ev3-l-motor', 'outC': None}, gyro_port=None) as f:
        assert f.motor_ports == ('outA', 'outB', 'outD')
        assert read(f, 'outD', 'driver_name').strip() == b'lego-ev3-l-motor'
        assert not os.path.exists(os.path.join(f.sysfs_root, 'lego-sensor', 'sensor0'))
        assert f.gyro_mode is None
        with pytest.raises(fake_ev3.FakeEV3Error):
            f.set_encoder_counts('outC', 1)


def test_given_root_dir_is_used_and_left_in_place(tmp_path):
    root = tmp_path / 'sys-class'
    f = FakeEV3(root_dir=str(root))
    f.close()
    assert (root / 'tacho-motor' / 'motor0' / 'position').exists()


# ---------------------------------------------------------------- counting io
def test_counting_io_counts_and_injects_failures(fake):
    io = fake.io
    rel = fake.relpath('outB', 'position')
    fd = io.open(fake.attribute_path('outB', 'position'), os.O_RDONLY)
    assert io.open_fds == {fd: rel}
    assert int(io.pread(fd, 32, 0)) == 0
    io.fail(rel, 'pread', errno.EIO)
    with pytest.raises(OSError) as e:
        io.pread(fd, 32, 0)
    assert e.value.errno == errno.EIO
    assert io.reads == 2 and io.by_path[('pread', rel)] == 2
    io.clear_failures()
    io.reset()
    assert io.pread(fd, 32, 0) and io.reads == 1
    io.close(fd)
    assert io.open_fds == {}
    io.fail(rel, 'open')
    with pytest.raises(OSError):
        io.open(fake.attribute_path('outB', 'position'), os.O_RDONLY)


def test_counting_io_without_root_uses_full_paths(tmp_path):
    io = CountingIO()
    path = str(tmp_path / 'x')
    fd = io.open(path, os.O_RDWR | os.O_CREAT)
    io.pwrite(fd, b'12\n', 0)
    assert io.writes_to(path) == [b'12\n']
    io.close(fd)


# ---------------------------------------------------------------- sensor models
def test_sensor_model_encoders_are_wheel_relative_to_link1_with_signs():
    s = SensorModel(0.034, motor_signs=(1, -1, 1, -1))
    th1 = 0.1
    d = 0.034 * (np.deg2rad(90.0) + th1)       # wheel turned 90 deg relative to link 1
    x = [d, d, th1, np.deg2rad(10.4), np.deg2rad(-10.6), 0, 0, 0, 0, 0]
    assert s.encoders(x) == (90, -90, 10, 11)
    # pure tilt with the wheels fixed on the ground: the encoders see -th1
    assert s.encoders([0, 0, np.deg2rad(5.0), 0, 0, 0, 0, 0, 0, 0])[:2] == (-5, 5)


def test_sensor_model_rounds_half_a_count_about_the_start_pose():
    s = SensorModel(0.034)
    step = 2 * np.pi / 360
    for frac, counts in ((0.49, 0), (-0.49, 0), (0.51, 1), (-0.51, -1)):
        assert s.encoders([0, 0, 0, frac * step, 0, 0, 0, 0, 0, 0])[2] == counts


def test_sensor_model_gyro_sign_bias_noise_and_limits():
    x = [0, 0, np.deg2rad(3.0), 0, 0, 0, 0, np.deg2rad(50.0), 0, 0]
    s = SensorModel(0.034, gyro_sign=-1, gyro_bias_dps=1.0)
    assert s.gyro(x, 0.0) == (-3, -49)
    assert s.gyro(x, 10.0) == (7, -49)           # the bias drifts the sensor's angle
    x[7] = np.deg2rad(1000.0)
    assert s.gyro(x, 0.0)[1] == -440
    noisy = SensorModel(0.034, gyro_noise_dps=2.0, rng=np.random.default_rng(7))
    rates = [noisy.gyro([0] * 10, 0.0)[1] for _ in range(2000)]
    assert all(isinstance(r, int) for r in rates)
    assert abs(np.mean(rates)) < 0.2 and 1.7 < np.std(rates) < 2.3
    again = SensorModel(0.034, gyro_noise_dps=2.0, rng=np.random.default_rng(7))
    assert [again.gyro([0] * 10, 0.0)[1] for _ in range(2000)] == rates
    with pytest.raises(ValueError, match='needs rng'):
        SensorModel(0.034, gyro_noise_dps=1.0)


def test_sensor_model_battery_sag_and_feeding_the_fake(fake):
    s = SensorModel(0.034, battery_v=8.2, battery_r_ohm=0.5)
    assert s.battery(0.0) == pytest.approx(8.2)
    assert s.battery(1.2) == pytest.approx(7.6)
    x = [0.01, -0.01, 0.0, 0.2, -0.1, 0, 0, 0, 0, 0]
    enc, gyro, volts = s.read(x, 0.0, current_a=1.2)
    fake.set_readings(enc, gyro, volts)
    assert tuple(int(read(fake, p, 'position')) for p in fake.motor_ports) == enc
    assert int(read(fake, 'battery', 'voltage_now')) == 7600000
