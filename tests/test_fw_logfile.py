"""tipbot_fw.logfile and tipbot_fw.replay: the log round-trips, damage is detected, runs replay."""
import numpy as np
import pytest

import fw_support as S
from tipbot_fw import logfile
from tipbot_fw.logfile import LogFormatError, col, read_log, write_log
from tipbot_fw.detector_core import DetectorRows
from tipbot_fw.replay import replay
from tipbot_fw.session import run_session


def some_rows(n=37, seed=6):
    return np.random.RandomState(seed).normal(size=(n, logfile.N_COLUMNS))


def test_round_trip(tmp_path):
    path = str(tmp_path / 'a.log')
    rows = some_rows()
    write_log(path, {'stop_reason': 'completed', 'nested': {'x': [1, 2.5]}}, rows)
    header, back = read_log(path)
    np.testing.assert_array_equal(back, rows)
    assert header['nested'] == {'x': [1, 2.5]} and header['format_version'] == 1
    assert [c['name'] for c in header['columns']] == logfile.COLUMN_NAMES
    assert not (tmp_path / 'a.log.tmp').exists()


def test_empty_log_round_trips(tmp_path):
    path = str(tmp_path / 'e.log')
    write_log(path, {}, np.zeros((0, logfile.N_COLUMNS)))
    assert read_log(path)[1].shape == (0, logfile.N_COLUMNS)


@pytest.fixture
def log_bytes(tmp_path):
    path = str(tmp_path / 'a.log')
    write_log(path, {'k': 'v'}, some_rows())
    with open(path, 'rb') as f:
        return path, f.read()


def rewrite(path, data):
    with open(path, 'wb') as f:
        f.write(data)


@pytest.mark.parametrize('cut', [1, 8, 100, 1000])
def test_truncated_log(log_bytes, cut):
    path, data = log_bytes
    rewrite(path, data[:-cut])
    with pytest.raises(LogFormatError, match='truncated: {} bytes, expected {}'.format(len(data) - cut, len(data))):
        read_log(path)


def test_truncated_inside_the_preamble(log_bytes):
    path, data = log_bytes
    for n in (0, 5, 20):
        rewrite(path, data[:n])
        with pytest.raises(LogFormatError, match='truncated'):
            read_log(path)


@pytest.mark.parametrize('where', [12, 40, -300, -2])
def test_corrupted_byte_fails_the_crc(log_bytes, where):
    path, data = log_bytes
    bad = bytearray(data)
    bad[where] ^= 0x10
    rewrite(path, bytes(bad))
    with pytest.raises(LogFormatError, match='corrupted: CRC32|truncated|unexpected bytes'):
        read_log(path)


def test_corrupted_body_names_the_crc(log_bytes):
    path, data = log_bytes
    bad = bytearray(data)
    bad[-300] ^= 0x01
    rewrite(path, bytes(bad))
    with pytest.raises(LogFormatError, match='corrupted: CRC32 is [0-9a-f]{8}, expected [0-9a-f]{8}'):
        read_log(path)


def test_not_a_log_and_trailing_garbage(log_bytes):
    path, data = log_bytes
    rewrite(path, b'{"json": true}')
    with pytest.raises(LogFormatError, match='not a tipbot log'):
        read_log(path)
    rewrite(path, data + b'\n')
    with pytest.raises(LogFormatError, match='1 unexpected bytes after the end'):
        read_log(path)


def test_ring_buffer_keeps_the_newest_rows_in_order():
    log = logfile.LogBuffer(5, DetectorRows((1, 1, 1, 1)))
    for k in range(12):
        log.mem[k % 5, 0] = k
    log.count = 12
    first, rows = log.ordered()
    assert first == 7 and rows[:, col('time_s')].tolist() == [7, 8, 9, 10, 11]
    # written in blocks that wrap around the ring, the file holds the same rows
    blocks = [b[:, col('time_s')].tolist() for b in log.file_blocks(size=3)]
    assert blocks == [[7, 8, 9], [10, 11]]


def test_log_written_block_by_block_from_the_ring(tmp_path):
    log = logfile.LogBuffer(7, DetectorRows((1, -1, 1, 1)))
    rng = np.random.RandomState(8)
    for k in range(17):
        log.mem[k % 7] = rng.normal(size=logfile.MEM_COLUMNS)
    log.count = 17
    path = str(tmp_path / 'ring.log')
    write_log(path, {'first_tick': log.first_tick()}, log.file_blocks(size=2), log.kept())
    header, rows = read_log(path)
    np.testing.assert_array_equal(rows, log.ordered()[1])
    assert header['first_tick'] == 10 and len(rows) == 7


def simulated_run(tmp_path, duration_s=2.0, log_max_rows=24000, estimator='kalman'):
    sim = S.Lockstep(x0=[0, 0, 0.04, 0.02, 0, 0, 0, 0, 0, 0], gyro_bias_dps=2,
                     disturbance=[0.5, 0.5, 0, 0, 0], enc_zero=(1000, -2000, 30, -40))
    gains = S.load()
    path = str(tmp_path / 'run.log')
    config = S.fw_config(start_pose_rad={'th1': 0.04, 'th2': 0.02}, log_max_rows=log_max_rows,
                         estimator=estimator)
    code, _ = run_session(sim.dev, gains, config, sim.clock, log_path=path, duration_s=duration_s,
                          say=lambda m: None)
    assert code == 0
    header, rows = read_log(path)
    return gains, (header, rows), [c['name'] for c in header['columns']].index


@pytest.mark.parametrize('estimator', ['kalman', 'detector'])
def test_replay_reproduces_the_run(tmp_path, estimator):
    gains, (header, rows), c = simulated_run(tmp_path, estimator=estimator)
    assert header['first_tick'] == 0 and len(rows) == 400
    again = replay(header, rows, gains)
    # the Kalman core's integers are bit-identical anywhere, the detector's floats on this machine
    np.testing.assert_array_equal(again, rows)
    # and the run was not trivial: a disturbance estimated, the estimates moving
    w, th1 = ('xi_w_r', 'xi_th1') if estimator == 'kalman' else ('w_r', 'xt_th1')
    assert np.abs(rows[:, c(w)]).max() > 0.1
    assert np.abs(rows[:, c(th1)]).max() > 0.01


@pytest.mark.parametrize('estimator', ['kalman', 'detector'])
def test_replay_from_a_wrapped_ring(tmp_path, estimator):
    gains, (header, rows), _ = simulated_run(tmp_path, log_max_rows=150, estimator=estimator)
    assert header['first_tick'] == 250 and len(rows) == 150
    np.testing.assert_array_equal(replay(header, rows, gains), rows)


@pytest.mark.parametrize('estimator, state', [('kalman', 'xi_th2_dot'), ('detector', 'xt_th2')])
def test_replay_detects_a_changed_raw_reading_and_other_gains(tmp_path, estimator, state):
    gains, (header, rows), c = simulated_run(tmp_path, duration_s=0.5, estimator=estimator)
    tampered = rows.copy()
    tampered[50, c('enc_2')] += 1
    again = replay(header, tampered, gains)
    assert np.abs(again[:50] - rows[:50]).max() == 0
    assert np.abs(again[51:, c(state)] - rows[51:, c(state)]).max() > 1e-4
    other = S.load(S.gains_doc(detector_pole=0.3))
    other.sha256 = 'another'
    with pytest.raises(ValueError, match='not the ones of the log'):
        replay(header, rows, other)
