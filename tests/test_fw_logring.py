"""tipbot_fw.record.container's bounded log: a head of the first rows, a ring of the last chunks, and
what a crash or a power cut in the middle of overwriting the ring leaves (fault injection on
the file's bytes)."""
import json

import numpy as np
import pytest

from tipbot_fw.record import container, logfile
from tipbot_fw.record.container import LogFormatError, LogWriter, read_log
from tipbot_fw.record.logfile import segments

COLUMNS = [('tick', ''), ('a', 'm'), ('b', 'V')]
HEAD, SLOTS, CHUNK = 100, 4, 50


def rows_of(first, n):
    """Rows that say which tick they are, and two values of that tick."""
    t = np.arange(first, first + n, dtype=float)
    return np.column_stack([t, np.sin(1.3 * t), 5 * np.cos(0.7 * t)])


def write_run(path, n, snapshot_before=None, keep=(HEAD, SLOTS, CHUNK), close=True):
    """A bounded log of n rows given in whole chunks (the loop's flushes), the last one partial.
    -> the file's bytes just before the chunk that starts at row snapshot_before was written."""
    w = LogWriter(path, COLUMNS, keep=keep)
    w.header({'kind': 'test'})
    before = None
    for first in range(0, n, CHUNK):
        if first == snapshot_before:
            with open(path, 'rb') as f:
                before = f.read()
        w.rows(rows_of(first, min(CHUNK, n - first)))
    if close:
        assert w.close({'ticks': n}) is None
    return w, before


def check_reads(header, rows):
    """What any bounded log that reads must be: rows in tick order, each the row of its tick,
    the parts and the gaps between them consistent with the ticks."""
    ticks = rows[:, 0].astype(int)
    assert np.all(np.diff(ticks) > 0)
    np.testing.assert_array_equal(rows, np.concatenate([rows_of(t, 1) for t in ticks]) if len(ticks) else rows)
    parts = segments(header, len(rows))
    expected = np.concatenate([rows_of(first, n)[:, 0] for first, n in parts]) if parts else np.zeros(0)
    np.testing.assert_array_equal(ticks, expected)


def test_a_long_run_keeps_its_head_and_its_last_chunks_in_a_file_of_fixed_size(tmp_path):
    sizes = []
    for n in (640, 1012):
        path = str(tmp_path / ('%d.log' % n))
        w, _ = write_run(path, n)
        header, rows = read_log(path)
        sizes.append(open(path, 'rb').read().rfind(b'TAIL'))     # where the end record starts
        # head 0..99; the ring's last 4 chunks: the partial last one and the 3 before it
        last = (n - HEAD - 1) // CHUNK * CHUNK + HEAD
        first_kept = last - (SLOTS - 1) * CHUNK
        assert header['segments'] == [[0, HEAD], [first_kept, n - first_kept]]
        assert header['not_kept'] == [[HEAD, first_kept - 1]] and w.not_kept() == [(HEAD, first_kept - 1)]
        assert w.dropped == first_kept - HEAD and 'incomplete' not in header
        np.testing.assert_array_equal(rows, np.concatenate([rows_of(0, HEAD), rows_of(first_kept, n - first_kept)]))
    assert sizes[0] == sizes[1]         # the file does not grow with the run


def test_a_run_that_fits_reads_whole_and_a_ring_that_never_wrapped_has_no_gap(tmp_path):
    path = str(tmp_path / 'short.log')
    write_run(path, 260)                                     # head 100, then 3 of the 4 slots
    header, rows = read_log(path)
    np.testing.assert_array_equal(rows, rows_of(0, 260))
    assert header['segments'] == [[0, 260]] and header['not_kept'] == []
    # rewritten whole (a tool), it is a log of rows in order: no ring
    container.write_log(str(tmp_path / 'again.log'), header, rows, COLUMNS)
    again, back = read_log(str(tmp_path / 'again.log'))
    np.testing.assert_array_equal(back, rows)
    assert 'ring' not in again


def test_the_first_rows_only_without_a_ring(tmp_path):
    path = str(tmp_path / 'head.log')
    w, _ = write_run(path, 300, keep=(120, 0, CHUNK))
    header, rows = read_log(path)
    np.testing.assert_array_equal(rows, rows_of(0, 120))
    assert w.dropped == 180 and w.not_kept() == [(120, 299)]
    assert 'segments' not in header      # a log as the first-rows-only logs were


@pytest.mark.parametrize('cut', [0, 1, 12, 13, 23, 24, 25, 600, 1223, 1227, 'all'])   # a slot: 1228 bytes
def test_a_power_cut_while_a_slot_is_overwritten_leaves_a_log_that_reads(tmp_path, cut):
    # the slot of chunk 12 (rows 700..749) held chunk 8 (rows 500..549); the write of chunk 12
    # reached the disk only up to byte `cut` of its slot (the rest: the old chunk's bytes), then
    # the power went: no TAIL either
    path = str(tmp_path / 'run.log')
    w, before = write_run(path, 750, snapshot_before=700, close=False)
    after = open(path, 'rb').read()
    slot_bytes = w.slot_bytes
    slot = w.ring_start + (12 % SLOTS) * slot_bytes
    n = slot_bytes if cut == 'all' else cut
    torn = bytearray(before)
    torn[slot:slot + n] = after[slot:slot + n]
    path2 = tmp_path / 'torn.log'
    path2.write_bytes(bytes(torn))
    header, rows = read_log(str(path2))
    check_reads(header, rows)
    assert 'incomplete' in header
    np.testing.assert_array_equal(rows[:HEAD], rows_of(0, HEAD))
    kept = set(rows[HEAD:, 0].astype(int).tolist())
    if cut == 'all':            # the new chunk whole: the newest 4 chunks, 550..749
        assert kept == set(range(550, 750))
    elif torn[slot:slot + slot_bytes] == before[slot:slot + slot_bytes]:
        assert kept == set(range(500, 700))     # nothing new reached it: the old chunk, 500..699
    else:                       # torn: dropped, and said; 550..699 remain
        assert kept == set(range(550, 700)) and header['ring_dropped_chunks'] == 1
    gaps = header['not_kept']
    assert gaps[0][0] == HEAD and gaps[0][1] == min(kept) - 1


@pytest.mark.parametrize('page', [0, 1, 2])
def test_pages_of_the_ring_reaching_the_disk_out_of_order(tmp_path, page):
    # without an fsync the kernel writes pages in any order: the written chunk with one 4 KB
    # page of its slot still old (page 1, 2: the ring's first two) is refused by its CRC,
    # never mixed into the rows; page 0: the file's first (the header's)
    path = str(tmp_path / 'run.log')
    w, before = write_run(path, 760, snapshot_before=750, close=False)
    after = bytearray(open(path, 'rb').read())
    lo = 0 if page == 0 else w.ring_start + (page - 1) * 4096
    hi = lo + 4096
    after[lo:hi] = before[lo:hi]
    path2 = tmp_path / 'pages.log'
    path2.write_bytes(bytes(after))
    try:
        header, rows = read_log(str(path2))
    except LogFormatError as e:      # the header's own page lost: refused in one line
        assert page == 0 and '\n' not in str(e)
        return
    check_reads(header, rows)


@pytest.mark.parametrize('end', [13, 200, 0.3, 0.45, 0.6, 0.75, 0.9, -10, -1])   # bytes, or a fraction
def test_a_ring_log_cut_anywhere_reads_with_what_is_intact(tmp_path, end):
    path = str(tmp_path / 'run.log')
    write_run(path, 1012)
    data = open(path, 'rb').read()
    cut = tmp_path / 'cut.log'
    cut.write_bytes(data[:int(end * len(data)) if isinstance(end, float) else end])
    try:
        header, rows = read_log(str(cut))
    except LogFormatError as e:
        assert end <= 200 and 'truncated' in str(e)
        return
    check_reads(header, rows)
    assert 'incomplete' in header


@pytest.mark.parametrize('ring', [[1, 2], {'head_rows': 100, 'slot_rows': 50, 'slots': 4, 'slot_bytes': 1228,
                                             'start_byte': 5}, {'head_rows': 100, 'slot_rows': 50, 'slots': 4,
                                                                'slot_bytes': 1000, 'start_byte': 8192}])
def test_a_header_with_a_ring_that_does_not_fit_its_rows_is_refused_in_one_line(tmp_path, ring):
    path = str(tmp_path / 'bad.log')
    w = LogWriter(path, COLUMNS)
    w._record(container.HEAD, json.dumps({'columns': w.columns, 'ring': ring}).encode())
    w.close({})
    with pytest.raises(LogFormatError, match='header field ring must') as e:
        read_log(path)
    assert '\n' not in str(e.value)


def test_the_last_rows_read_even_when_the_first_ones_end_damaged(tmp_path):
    # a power cut that left a page of the head's last record unwritten (zeros): the head reads
    # up to it, the ring (on its own pages, from a fixed byte) reads whole
    path = str(tmp_path / 'run.log')
    w, _ = write_run(path, 1012, close=False)
    data = bytearray(open(path, 'rb').read())
    last_head_record = data.rfind(b'ROWS', 0, w.ring_start)
    data[last_head_record + 30:last_head_record + 60] = bytes(30)
    cut = tmp_path / 'cut.log'
    cut.write_bytes(bytes(data))
    header, rows = read_log(str(cut))
    check_reads(header, rows)
    assert 'incomplete' in header and header["segments"] == [[0, 50], [850, 162]]


@pytest.mark.parametrize('max_rows, head_rows, needed, plan', [
    (24000, 6000, None, (6000, 360, 50)),     # the defaults: 30 s, then the last 90 s at 5 ms
    (24000, 6000, 601, (601, 0, 50)),         # a run of --duration 3 s: every row, no ring
    (24000, 6000, 24001, (6000, 360, 50)),
    (300, 6000, None, (150, 3, 50)),          # the head takes at most half
    (1000, 120, None, (100, 18, 50)),         # whole chunks
    (1000, 0, None, (0, 20, 50)),             # the last rows only
    (149, 50, None, (149, 0, 50)),            # no room for 2 chunks beside a head: the first rows
])
def test_what_a_run_keeps_of_its_rows(max_rows, head_rows, needed, plan):
    assert logfile.keep_plan(max_rows, head_rows, needed) == plan


def test_a_ring_without_a_head_keeps_the_last_rows(tmp_path):
    path = str(tmp_path / 'tail.log')
    write_run(path, 333, keep=(0, 3, CHUNK))
    header, rows = read_log(path)
    np.testing.assert_array_equal(rows, rows_of(200, 133))    # 200..249, 250..299, 300..332 (partial)
    assert header['segments'] == [[200, 133]] and header['not_kept'] == [[0, 199]]
