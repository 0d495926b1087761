"""`python -m hostsim export LOG --csv`: a log as CSV whose header names carry their units."""
import csv
import json
import os
import re

import numpy as np
import pytest

from hostsim.logs import export
from tipbot_fw.record import logfile
from tipbot_fw.cores.detector_rows import DetectorRows


def a_log(path, columns=DetectorRows.columns, kind=None, nrows=30, seed=4):
    rng = np.random.RandomState(seed)
    rows = rng.normal(size=(nrows, len(columns))) * 10.0 ** rng.randint(-6, 6, size=(1, len(columns)))
    rows[:, 0] = np.arange(nrows) * 0.005
    header = {'ts_s': 0.005, 'stop_reason': 'completed'}
    if kind:
        header['kind'] = kind
    logfile.write_log(str(path), header, rows, columns=columns)
    return rows


def test_a_run_log_exports_every_value_exactly_with_unit_names(tmp_path, capsys):
    rows = a_log(tmp_path / 'run.log')
    assert export.main([str(tmp_path / 'run.log'), '--csv']) == 0
    assert 'export: %s' % (tmp_path / 'run.csv') in capsys.readouterr().out
    with open(str(tmp_path / 'run.csv')) as f:
        table = list(csv.reader(f))
    names = table[0]
    assert names[:6] == ['time_s', 'tick_s', 'enc_r_count', 'enc_l_count', 'enc_2_count', 'enc_3_count']
    for name in ('gyro_rate_deg_per_s', 'battery_v', 'y_th1_rad', 'y_d_r_m', 'y_th1_dot_rad_per_s',
                 'xt_d_l_dot_m_per_s', 'w_r_V', 'u_cmd_th3_V', 'duty_r_pct', 'flags'):
        assert name in names
    # identifiers pandas and spreadsheets take as they are: unique, no spaces or brackets
    assert len(set(names)) == len(names) and all(re.match(r'^[A-Za-z_][A-Za-z0-9_]*$', n) for n in names)
    np.testing.assert_array_equal(np.array(table[1:], dtype=float), rows)
    with open(str(tmp_path / 'run.header.json')) as f:
        header = json.load(f)
    assert header['stop_reason'] == 'completed' and len(header['columns']) == len(names)


def test_any_kind_of_log_exports_its_own_columns(tmp_path):
    columns = [('time_s', 's'), ('position', 'count'), ('duty', '%')]
    rows = a_log(tmp_path / 'm.log', columns=columns, kind='identify')
    out = str(tmp_path / 'elsewhere' / 'motor.csv')
    os.makedirs(os.path.dirname(out))
    assert export.export_csv(str(tmp_path / 'm.log'), out) == (out, str(tmp_path / 'elsewhere' / 'motor.header.json'))
    with open(out) as f:
        table = list(csv.reader(f))
    assert table[0] == ['time_s', 'position_count', 'duty_pct']
    np.testing.assert_array_equal(np.array(table[1:], dtype=float), rows)


@pytest.mark.parametrize('make, message', [
    (lambda p: None, 'no such log file'),
    (lambda p: open(p, 'wb').write(b'TIPBLOG\n\x02\x00'), 'truncated'),     # cut inside the preamble
])
def test_a_log_that_cannot_be_read_gets_one_line(tmp_path, capsys, make, message):
    path = str(tmp_path / 'bad.log')
    make(path)
    assert export.main([path, '--csv']) == 2
    err = capsys.readouterr().err
    assert err.startswith('export: error: %s: ' % path) and message in err and len(err.splitlines()) == 1


def test_a_kalman_log_exports_the_physical_columns_the_replay_rebuilds(tmp_path, capsys):
    # the rows hold raw readings and the filter's integer state: the CSV adds x^, w^, u, u_cmd
    # and the bias as tipbot_fw.record.replay.signals() makes them, with the gains found by their hash
    import fw_support as S
    from tipbot_fw.gains import load_gains
    from tipbot_fw.record.replay import signals
    from tipbot_fw.session import run_session
    (tmp_path / 'robot').mkdir()
    gains_path = S.write_json(tmp_path / 'robot' / 'gains-x.json', S.gains_doc())
    gains = load_gains(gains_path)
    sim = S.Lockstep(x0=[0, 0, 0.02, 0, 0, 0, 0, 0, 0, 0], gyro_bias_dps=1)
    log = str(tmp_path / 'robot' / 'run.log')
    assert run_session(sim.dev, gains, S.fw_config(), sim.clock, log_path=log, duration_s=0.5, say=lambda m: None)[0] == 0
    assert export.main([log, '--csv']) == 0
    with open(str(tmp_path / 'robot' / 'run.csv')) as f:
        table = list(csv.reader(f))
    names, values = table[0], np.array(table[1:], dtype=float)
    header, rows = logfile.read_log(log)
    sig = signals(header, rows, gains)
    assert names[:len(header['columns'])] == [export.column_name(c['name'], c['unit']) for c in header['columns']]
    np.testing.assert_array_equal(values[:, :len(header['columns'])], rows)
    for name, expected in (('xt_th1_rad', sig.x_hat[:, 2]), ('xt_d_r_m', sig.x_hat[:, 0]),
                           ('w_r_V', sig.w_hat[:, 0]), ('u_th3_V', sig.u[:, 4]),
                           ('u_cmd_l_V', sig.u_cmd[:, 1])):
        np.testing.assert_array_equal(values[:, names.index(name)], expected, err_msg=name)
    assert np.ptp(values[:, names.index('xt_th1_rad')]) > 1e-3     # not vacuous: the estimate moved
    # link 1 has no motor: no input, disturbance or command columns that would always read 0
    assert not [n for n in names if n.endswith('_th1_V')]
    bias = values[:, names.index('gyro_bias_deg_per_s')]
    assert abs(bias[0] - 1.0) < 1e-6           # the calibrated bias the filter starts from
    # without its gains (not beside it, not in gains/), one line that says what to do
    os.unlink(gains_path)
    capsys.readouterr()
    assert export.main([log, '--csv']) == 2
    err = capsys.readouterr().err
    assert "a Kalman log's physical columns need the gains it ran" in err and len(err.splitlines()) == 1


def test_csv_is_the_default_format(tmp_path, capsys):
    a_log(tmp_path / 'run.log')
    assert export.main([str(tmp_path / 'run.log')]) == 0
    assert (tmp_path / 'run.csv').read_text().splitlines()[0].startswith('time_s')
