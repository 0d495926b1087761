"""`python -m hostsim export LOG --csv`: a log as CSV whose header names carry their units."""
import csv
import json
import os
import re

import numpy as np
import pytest

from hostsim.logs import export
from tipbot_fw import logfile


def a_log(path, columns=logfile.COLUMNS, kind=None, nrows=30, seed=4):
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
