"""tipbot_fw.record.logfile and tipbot_fw.record.replay: the log round-trips, damage is detected, runs replay."""
import errno
import json
import os
import struct
import zlib

import numpy as np
import pytest

import fw_support as S
from tipbot_fw.record import logfile
from tipbot_fw.record.logfile import LogFormatError, LogWriteError, LogWriter, read_log, write_log
from tipbot_fw.record.replay import replay
from tipbot_fw.session import run_session
from tipbot_fw.cores.detector_rows import DetectorRows

col = DetectorRows.col


def some_rows(n=37, seed=6):
    return np.random.RandomState(seed).normal(size=(n, len(DetectorRows.columns)))


def test_round_trip(tmp_path):
    path = str(tmp_path / 'a.log')
    rows = some_rows()
    write_log(path, {'stop_reason': 'completed', 'nested': {'x': [1, 2.5]}}, rows, DetectorRows.columns)
    header, back = read_log(path)
    np.testing.assert_array_equal(back, rows)
    assert header['nested'] == {'x': [1, 2.5]} and header['format_version'] == 2 and 'incomplete' not in header
    assert [c['name'] for c in header['columns']] == DetectorRows.column_names
    assert not (tmp_path / 'a.log.tmp').exists()


def test_empty_log_round_trips(tmp_path):
    path = str(tmp_path / 'e.log')
    write_log(path, {}, np.zeros((0, len(DetectorRows.columns))), DetectorRows.columns)
    assert read_log(path)[1].shape == (0, len(DetectorRows.columns))


@pytest.fixture
def log_bytes(tmp_path):
    path = str(tmp_path / 'a.log')
    write_log(path, {'k': 'v'}, some_rows(), DetectorRows.columns)
    with open(path, 'rb') as f:
        return path, f.read()


def rewrite(path, data):
    with open(path, 'wb') as f:
        f.write(data)


def _rows_records(data):
    """(start, end) of each ROWS record of a format-2 log."""
    out, pos = [], len(logfile.MAGIC) + 4
    while pos < len(data):
        tag, n, _ = struct.unpack_from('<4sII', data, pos)
        if tag == b'ROWS':
            out.append((pos, pos + 16 + n))
        pos += 16 + n
    return out


@pytest.fixture
def chunked_log(tmp_path):
    """A log whose 37 rows are in chunks of 10, as a run writes them."""
    path = str(tmp_path / 'c.log')
    rows = some_rows()
    w = LogWriter(path, DetectorRows.columns, reserve_rows=1000)
    w.header({'k': 'v'})
    for i in range(0, len(rows), 10):
        w.rows(rows[i:i + 10])
    assert w.close({'stop_reason': 'completed'}) is None
    with open(path, 'rb') as f:
        return path, f.read(), rows


@pytest.mark.parametrize('cut', [1, 8, 100, 1000, 2000])
def test_a_log_cut_short_returns_its_intact_rows_and_says_so(chunked_log, cut):
    path, data, rows = chunked_log
    rewrite(path, data[:-cut])
    header, back = read_log(path)
    intact = sum(1 for a, b in _rows_records(data) if b <= len(data) - cut)
    np.testing.assert_array_equal(back, rows[:10 * intact][:len(back)])
    assert len(back) == min(37, 10 * intact)
    assert 'stop_reason' not in header and header['k'] == 'v'
    assert header['incomplete'].endswith('intact rows (a crash, a power cut or a full disk)')


def test_a_power_cut_in_reserved_space_reads_as_cut(chunked_log):
    # the file keeps its reserved length; what was never written reads as zeros
    path, data, rows = chunked_log
    a, b = _rows_records(data)[2]
    rewrite(path, data[:a] + bytes(100000))
    header, back = read_log(path)
    assert len(back) == 20 and 'reserved and never written' in header['incomplete']


def test_truncated_inside_the_preamble_or_the_header(chunked_log):
    path, data, _ = chunked_log
    for n in (0, 5, 20, 200):
        rewrite(path, data[:n])
        with pytest.raises(LogFormatError, match='truncated'):
            read_log(path)


@pytest.mark.parametrize('where', [30, 'rows'])
def test_a_flipped_bit_before_the_end_is_refused(chunked_log, where):
    path, data, _ = chunked_log
    i = where if where != 'rows' else _rows_records(data)[1][0] + 40
    bad = bytearray(data)
    bad[i] ^= 0x10
    rewrite(path, bytes(bad))
    with pytest.raises(LogFormatError, match='corrupted: CRC32 of the (HEAD|ROWS) record at byte [0-9]+ is [0-9a-f]{8}, '
                                             'expected [0-9a-f]{8}'):
        read_log(path)


def test_a_flipped_bit_in_a_record_header_is_refused(chunked_log):
    path, data, _ = chunked_log
    bad = bytearray(data)
    bad[_rows_records(data)[1][0] + 5] ^= 0x01        # a row count that would skip the next records
    rewrite(path, bytes(bad))
    with pytest.raises(LogFormatError, match='corrupted: bad record header'):
        read_log(path)


def test_a_version_1_log_still_reads(tmp_path):
    # version 1: counts, header, body and one CRC over them (docs/log-format.md)
    header = {'columns': logfile.columns_header(DetectorRows.columns), 'k': 1}
    text = json.dumps(header).encode()
    rows = some_rows(3)
    counts = struct.pack('<IIIQ', 1, len(text), len(DetectorRows.columns), 3)
    body = rows.astype('<f8').tobytes()
    crc = zlib.crc32(counts + text + body) & 0xffffffff
    path = str(tmp_path / 'v1.log')
    rewrite(path, logfile.MAGIC + counts + text + body + struct.pack('<I', crc))
    h, back = read_log(path)
    assert h['k'] == 1 and np.array_equal(back, rows)


def test_a_full_disk_keeps_what_was_written(tmp_path, monkeypatch):
    path = str(tmp_path / 'full.log')
    w = LogWriter(path, DetectorRows.columns)
    w.header({})
    rows = some_rows(30)
    w.rows(rows[:10])
    real = os.pwrite

    def full(fd, data, pos):
        raise OSError(errno.ENOSPC, 'No space left on device')
    monkeypatch.setattr(os, 'pwrite', full)
    assert w.rows(rows[10:20]) is False
    monkeypatch.setattr(os, 'pwrite', real)
    problem = w.close({'stop_reason': 'completed'})
    assert problem == 'writing the log failed after 10 rows: No space left on device'
    header, back = read_log(path)
    assert np.array_equal(back, rows[:10]) and 'no trailer' in header['incomplete']


def test_no_room_for_the_log_is_found_before_anything_runs(tmp_path):
    with pytest.raises(LogWriteError, match='cannot write the log .*/nonexistent/x.log'):
        LogWriter(str(tmp_path / 'nonexistent' / 'x.log'), DetectorRows.columns)


def test_not_a_log_and_trailing_garbage(chunked_log):
    path, data, _ = chunked_log
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
        log.mem[k % 7] = rng.normal(size=len(DetectorRows.mem_names))
    log.count = 17
    path = str(tmp_path / 'ring.log')
    write_log(path, {'first_tick': log.first_tick()}, log.file_blocks(size=2), DetectorRows.columns)
    header, rows = read_log(path)
    np.testing.assert_array_equal(rows, log.ordered()[1])
    assert header['first_tick'] == 10 and len(rows) == 7


def simulated_run(tmp_path, duration_s=2.0, estimator='kalman', name='run.log', **config):
    sim = S.Lockstep(x0=[0, 0, 0.04, 0.02, 0, 0, 0, 0, 0, 0], gyro_bias_dps=2,
                     disturbance=[0.5, 0.5, 0, 0, 0], enc_zero=(1000, -2000, 30, -40))
    gains = S.load()
    path = str(tmp_path / name)
    config = S.fw_config(start_pose_rad={'th1': 0.04, 'th2': 0.02}, estimator=estimator, **config)
    said = []
    code, _ = run_session(sim.dev, gains, config, sim.clock, log_path=path, duration_s=duration_s,
                          say=said.append)
    assert code == 0
    header, rows = read_log(path)
    header['said'] = said
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
def test_a_run_beyond_log_max_rows_keeps_its_start_and_its_end_and_both_replay_exactly(tmp_path, estimator):
    # 412 ticks; the file holds 300 rows: the first 100, then a ring of 4 chunks of 50 whose last
    # chunk (ticks 400..411) is partial and overwrote ticks 200..249: ticks 250..411 are kept
    gains, (header, rows), c = simulated_run(tmp_path, duration_s=2.06, estimator=estimator,
                                             log_max_rows=300, log_head_rows=100)
    assert header['ticks'] == 412 and len(rows) == 100 + 162
    assert header['segments'] == [[0, 100], [250, 162]] and header['not_kept'] == [[100, 249]]
    assert header['rows_not_recorded'] == 150 and 'incomplete' not in header
    assert any('ticks 100..249: not kept' in m for m in header['said'])
    # the very rows of the same run logged whole, in tick order
    _, (_, whole), _ = simulated_run(tmp_path, duration_s=2.06, estimator=estimator, name='whole.log')
    np.testing.assert_array_equal(rows, np.concatenate([whole[:100], whole[250:]]))
    assert rows[100, c('time_s')] == pytest.approx(250 * 0.005, abs=1e-9)
    # the head from the start, the tail re-seeded from its first row: both replay bit for bit
    np.testing.assert_array_equal(replay(header, rows, gains), rows)
    # and a changed reading in the tail is caught (the tail is replayed, not copied)
    bad = rows.copy()
    bad[200, c('gyro_rate')] += 50
    assert np.any(replay(header, bad, gains)[200:] != bad[200:])


@pytest.mark.parametrize('estimator', ['kalman', 'detector'])
def test_rows_reach_the_file_while_the_robot_runs(tmp_path, estimator):
    # a copy of the file taken mid-run reads, with the rows of every chunk written so far, and
    # replays: the header, the calibration and the encoder zeros reached the file before them
    sim = S.Lockstep()
    path = str(tmp_path / 'run.log')
    seen = []
    gains = S.load()

    def peek(s):
        if s.steps in (120, 260):
            seen.append(read_log(path))
    sim.on_step = peek
    run_session(sim.dev, gains, S.fw_config(estimator=estimator), sim.clock, log_path=path, duration_s=2.0,
                say=lambda m: None)
    (h1, r1), (h2, r2) = seen
    assert 100 <= len(r1) <= 120 and 250 <= len(r2) <= 260 and 'reserved and never written' in h1['incomplete']
    assert h1['calibration'] and h1['encoder_offsets'] == [0, 0, 0, 0] and h1['estimator'] == estimator
    np.testing.assert_array_equal(r2, read_log(path)[1][:len(r2)])
    np.testing.assert_array_equal(replay(h2, r2, gains), r2)


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
