"""The EV3 IR remote (tipbot_fw.drive.ir_remote): the buttons' commands, the read rate and failed reads,
the configuration, the device layer on a fake EV3 tree, and a run driven by its buttons."""
import math

import numpy as np
import pytest

import fw_support as S
from conftest import PHYSICAL_GAINS
from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw import cli
from tipbot_fw import config as fw_config
from tipbot_fw.record.logfile import read_log
from tipbot_fw.io.ev3dev import Ev3Devices, Ev3SetupError
from tipbot_fw.drive.ir_remote import READ_PERIOD_S, IrRemote, command

LIMITS = {'speed_mps': 0.2, 'yaw_rate_dps': 90.0}
W = math.radians(90.0)


@pytest.mark.parametrize('code, expected', [
    (0, (0.0, 0.0)), (5, (0.2, 0.0)), (8, (-0.2, 0.0)),          # both up, both down
    (6, (0.0, -W)), (7, (0.0, W)),                                # turn in place right, left
    (1, (0.1, -W / 2)), (3, (0.1, W / 2)),                        # one wheel: an arc
    (2, (-0.1, W / 2)), (4, (-0.1, -W / 2)),
    (9, (0.0, 0.0)), (10, (0.0, 0.0)), (11, (0.0, 0.0)), (12, (0.0, 0.0)), (-1, (0.0, 0.0))])
def test_each_button_code_is_a_tank_command(code, expected):
    assert command(code, 0.2, W) == pytest.approx(expected)


def test_the_sensor_is_read_at_most_every_read_period_and_a_failed_read_is_no_button():
    codes = [5, 6, OSError('gone'), 99, 0]
    reads = []

    def read():
        reads.append(1)
        c = codes[len(reads) - 1]
        if isinstance(c, Exception):
            raise c
        return c
    ir = IrRemote(read, LIMITS, 'ir:in3 channel 1')
    per = int(round(READ_PERIOD_S / 0.005))     # ticks of 5 ms a read period
    got = [ir.poll(k * READ_PERIOD_S / per) for k in range(5 * per)]
    assert len(reads) == 5                      # one read a period
    assert got[0] == pytest.approx((0.2, 0.0)) and got[per - 1] == got[0]
    assert got[per] == pytest.approx((0.0, -W))
    assert got[2 * per] == (0.0, 0.0) and got[3 * per] == (0.0, 0.0)   # failed read, unknown code
    assert ir.summary() == {'host': 'ir:in3 channel 1', 'obeyed': 2, 'dropped': {'failed reads': 2}}


def test_the_configuration_names_the_port_and_refuses_the_gyros():
    cfg = fw_config.defaults()
    assert cfg['ports']['ir_remote'] is None and cfg['ir_remote_channel'] == 1
    ok = fw_config.config_from_overrides({'ports': {'ir_remote': 'in3'}, 'ir_remote_channel': 2})
    assert ok['ports']['ir_remote'] == 'in3'
    with pytest.raises(fw_config.ConfigError, match=r"cfg.json: field ports.ir_remote is in2, the gyro's port too"):
        fw_config.config_from_overrides({'ports': {'ir_remote': 'in2'}}, 'cfg.json')
    with pytest.raises(fw_config.ConfigError, match=r'field ir_remote_channel'):
        fw_config.config_from_overrides({'ir_remote_channel': 5}, 'cfg.json')


def test_the_device_layer_sets_ir_remote_mode_and_reads_the_channel():
    fake = FakeEV3(ir_port='in3')
    try:
        cfg = fw_config.config_from_overrides({'ports': {'ir_remote': 'in3'}, 'ir_remote_channel': 2})
        with Ev3Devices(cfg, fake.sysfs_root, io=fake.io) as d:
            assert fake.ir_mode() == 'IR-REMOTE' and d.ir_remote == ('in3', 2)
            fake.set_ir_buttons(2, 7)
            fake.set_ir_buttons(1, 5)           # another channel: not this remote
            assert d.read_ir_remote() == 7
            fake.set_ir_buttons(2, 0)
            assert d.read_ir_remote() == 0
        with Ev3Devices(fw_config.defaults(), fake.sysfs_root, io=fake.io) as d:
            assert d.ir_remote is None          # not configured: not touched
    finally:
        fake.close()


def test_a_configured_ir_remote_that_is_missing_is_named():
    fake = FakeEV3()
    try:
        cfg = fw_config.config_from_overrides({'ports': {'ir_remote': 'in4'}})
        with pytest.raises(Ev3SetupError) as e:
            Ev3Devices(cfg, fake.sysfs_root, io=fake.io)
        assert e.value.problems == ['port in4: no sensor found (expected lego-ev3-ir)']
        assert e.value.fields == ['ports.ir_remote']
    finally:
        fake.close()


def test_a_run_driven_by_the_ir_remotes_buttons(tmp_path, capsys):
    # both buttons up (code 5) on channel 1 of the sensor on in3: the reference drives forward
    config = S.write_json(tmp_path / 'ir.json', {
        'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05},
        'ports': {'ir_remote': 'in3'}})
    log = str(tmp_path / 'run.log')
    with FakeEV3(str(tmp_path / 'sys'), battery_v=8.2, ir_port='in3') as fake:
        fake.set_readings((0, 0, 0, 0))
        fake.set_ir_buttons(1, 5)
        code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', config, '--duration', '1.0',
                         '--log', log, '--sysfs-root', fake.sysfs_root])
    err = capsys.readouterr().err
    assert code == 0, err
    assert 'driving by the IR remote on in3, channel 1' in err
    assert 'remote: ' in err and 'obeyed from ir:in3 channel 1' in err
    header, rows = read_log(log)
    names = [c['name'] for c in header['columns']]
    assert header['remote'] == {'host': 'ir:in3 channel 1'}
    v_r, v_l = rows[:, names.index('ref_v_r')], rows[:, names.index('ref_v_l')]
    assert v_r.max() > 0.1 and np.allclose(v_r, v_l)        # forward, no turn


def test_without_an_ir_remote_configured_a_run_stands(tmp_path, capsys):
    config = S.write_json(tmp_path / 'quick.json', {
        'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})
    log = str(tmp_path / 'run.log')
    with FakeEV3(str(tmp_path / 'sys'), battery_v=8.2, ir_port='in3') as fake:
        fake.set_readings((0, 0, 0, 0))
        fake.set_ir_buttons(1, 5)       # plugged in and pressed, but not configured
        code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', config, '--duration', '0.5',
                         '--log', log, '--sysfs-root', fake.sysfs_root])
    err = capsys.readouterr().err
    assert code == 0, err
    assert 'IR remote' not in err
    header, rows = read_log(log)
    names = [c['name'] for c in header['columns']]
    assert 'remote' not in header and not rows[:, names.index('ref_v_r')].any()
