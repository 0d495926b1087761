"""Run log: per-tick rows in a preallocated ring, written to the file in chunks in the loop's
slack (docs/log-format.md), and the reader that makes a log's file columns of them. The container
(records, CRCs, reading a log cut short) is tipbot_fw.record.container.

Each core declares its own row (tipbot_fw.cores: DetectorRows, KalmanRows): its memory row
(mem_names, row_bytes, flags_index), the file's columns and to_file(), which makes the second
from the first; the file stores the memory rows as they are and read_log() converts them,
knowing the layout from the log's header (layout_from_header).

Python 3.5-safe; the reader (read_log) is what host tools use.
"""
import os
import struct
import time

import numpy as np

from tipbot_fw.cores.detector_rows import DetectorRows
from tipbot_fw.cores.kalman_rows import KalmanRows
from tipbot_fw.record import container
from tipbot_fw.record.container import FORMAT_VERSION, MAGIC, LogFormatError, LogWriteError, LogWriter  # noqa: F401

# The clock at the tick's start and after its writes, the first two slots of every core's row:
# packed by the loop, made time_s and tick_s on reading
TIMES = struct.Struct('<2d')

LAYOUTS = {'detector': DetectorRows, 'kalman': KalmanRows}


def layout_from_header(header):
    """The row layout of a run log's header (a log without `estimator`, of a firmware before the
    Kalman core, has the detector's). KeyError, TypeError, ValueError if the header lacks it."""
    return LAYOUTS[header.get('estimator', 'detector')].from_header(header)


# Rows a chunk of the file holds: written in the slack of one tick every CHUNK_ROWS ticks
# (0.25 s at 5 ms), so a crash or a power cut loses at most that much of what the file had
# been sent; the ring in memory holds RING_CHUNKS chunks, so a chunk may wait for a tick with
# slack (tipbot_fw.loop) without being overwritten. A chunk is also the slot of the file's ring
# (tipbot_fw.record.container): a long run's file keeps its head and its last chunks.
CHUNK_ROWS = 50
RING_CHUNKS = 8


def keep_plan(max_rows, head_rows, needed_rows=None, chunk_rows=CHUNK_ROWS):
    """What a run's file keeps of its rows -> (head, slots, chunk_rows) for LogWriter's keep:
    every row when the run cannot outlast max_rows (needed_rows, from --duration); else the
    first head_rows (at most half of max_rows, whole chunks) and a ring of the last ones in the
    rest; with room for fewer than two chunks in the ring, the first max_rows only."""
    if needed_rows is not None and needed_rows <= max_rows:
        return int(needed_rows), 0, chunk_rows
    head = min(int(head_rows), int(max_rows) // 2) // chunk_rows * chunk_rows
    slots = (int(max_rows) - head) // chunk_rows
    if slots < 2:
        return int(max_rows), 0, chunk_rows
    return head, slots, chunk_rows


class LogBuffer(object):
    """Preallocated rows; a ring when a run outlives it.

    `rows` is the core's row layout (DetectorRows or KalmanRows); tick k's row is packed
    (struct, little-endian, in-memory layout: the first two slots the tick's clock readings,
    TIMES) into the bytearray `data` at byte offset (k % capacity) * rows.row_bytes; `mem` is a
    float64 view of the same memory. The loop keeps `count` (rows ever stored).

    With a ``writer`` (a tipbot_fw.record.container.LogWriter, which decides what the file keeps:
    its ``keep``), the rows go to the file in whole chunks: flush() writes the rows not yet
    written, so the ring needs only a few chunks; without one the ring keeps the newest
    ``capacity`` rows (bench, tests).
    """

    def __init__(self, capacity, rows, writer=None, chunk_rows=CHUNK_ROWS):
        self.capacity = int(capacity)
        self.rows = rows
        self.row_bytes = rows.row_bytes
        self.data = bytearray(self.capacity * self.row_bytes)
        self.mem = np.frombuffer(self.data, dtype='<f8').reshape(self.capacity, self.row_bytes // 8)
        self.count = 0
        self.t0 = 0.0       # the clock at the start of the first tick (set by the loop)
        self.writer = writer
        self.chunk_rows = chunk_rows
        self.flushed = 0    # rows sent to the writer (or dropped beyond max_rows)
        self.first_info = None  # () -> dict for an INFO record before the first rows (the zeros)

    @classmethod
    def for_file(cls, writer, rows, chunk_rows=CHUNK_ROWS):
        return cls(chunk_rows * RING_CHUNKS, rows, writer, chunk_rows)

    def flush(self, end=None):
        """Write the rows stored and not yet written, outside the ticks: during a run (``end``:
        the loop's count) up to the last whole chunk, the file's unit (the rest waits for the
        next flush); at the end (no ``end``) all of them. Never raises."""
        end = self.count if end is None else end - end % self.chunk_rows
        start = max(self.flushed, end - self.capacity)
        if self.writer is None or end <= start:
            return
        if self.first_info is not None:
            info = self.first_info()
            info['log_t0'] = self.t0
            self.writer.info(info)
            self.first_info = None
        self.writer.rows_bytes(*self._block(start, end))
        self.flushed = end

    def _block(self, start, stop):
        """The rows start..stop as the file stores them: the memory layout's bytes as they are
        (no conversion on the brick: read_log derives the file layout)."""
        p, q = (start % self.capacity) * self.row_bytes, (stop - start) * self.row_bytes
        end = p + q
        if end <= len(self.data):
            return self.data[p:end], stop - start
        return self.data[p:] + self.data[:end - len(self.data)], stop - start

    def not_recorded(self):
        """Rows stored but not kept in the file (a long run's middle, LogWriter.not_kept)."""
        return 0 if self.writer is None else self.writer.dropped

    def first_tick(self):
        """Index of the tick of the oldest row kept."""
        return max(0, self.count - self.capacity)

    def kept(self):
        """Number of rows kept."""
        return min(self.count, self.capacity)

    def file_blocks(self, size=2048):
        """The kept rows, oldest first, in the file layout, in blocks of at most `size` rows."""
        n = self.kept()
        start = self.first_tick() % self.capacity
        for i in range(0, n, size):
            p = (start + i) % self.capacity
            end = p + min(size, n - i)
            if end <= self.capacity:
                block = self.mem[p:end]
            else:                                   # the block wraps around the ring
                block = np.concatenate((self.mem[p:], self.mem[:end - self.capacity]))
            yield self.rows.to_file(block, self.t0)

    def ordered(self):
        """-> (index of the first kept tick, all kept rows oldest first in the file layout)."""
        blocks = list(self.file_blocks())
        rows = np.concatenate(blocks) if blocks else np.zeros((0, len(self.rows.columns)))
        return self.first_tick(), rows


def default_path(kind):
    """Where a log goes without --log: KIND-YYYYmmdd-HHMMSS.log in logs/ when the current
    directory holds the firmware package (a checkout, or the brick's install directory, whose
    logs/ `make logs` fetches), else in the current directory (the launcher runs in logs/)."""
    name = time.strftime(kind + '-%Y%m%d-%H%M%S.log')
    if os.path.isdir('tipbot_fw'):
        if not os.path.isdir('logs'):
            os.makedirs('logs')
        return os.path.join('logs', name)
    return name


def columns_header(columns):
    return [{'name': n, 'unit': u} for n, u in columns]


# What a run's log file stores: the memory rows of its core's layout, converted when read.
STORED_LAYOUT = 'memory'


def open_run_log(path, keep, rows):
    """A LogWriter for a run log whose rows are memory rows of the layout `rows`
    (LogBuffer.flush), keeping what `keep` says (keep_plan); the run's header must say which
    layout (rows.header())."""
    return LogWriter(path, [(n, '') for n in rows.mem_names], layout=STORED_LAYOUT, keep=keep)


def segments(header, nrows):
    """-> [[first tick, rows]] of each run of consecutive ticks a log's rows hold, in order: one
    for a log that holds a run from its first tick (or a version-1 ring's last rows), the head
    and the kept tail of a long run's bounded log (header['segments'], header['not_kept'])."""
    return header.get('segments') or [[header.get('first_tick', 0), nrows]]


def segment_rows(header, nrows):
    """-> [(row index, first tick)] where each of segments() begins among a log's rows."""
    out, i = [], 0
    for first, n in segments(header, nrows):
        out.append((i, first))
        i += n
    return out


def tick_indices(header, nrows):
    """-> the tick of each of a log's nrows rows (int array), from its segments."""
    parts = [np.arange(first, first + n) for first, n in segments(header, nrows)]
    return np.concatenate(parts).astype(int) if parts else np.zeros(0, dtype=int)


def read_log(path):
    """-> (header, rows in the file layout of the log's core). A run log whose file stores memory
    rows (format 2) is converted here with the layout its header describes (the core, the
    polarities or the fixed-point format, the encoder zeros) and its log_t0, so every reader
    sees the columns of docs/log-format.md. LogFormatError as container.read_log."""
    header, rows = container.read_log(path)
    if header.get('layout') == STORED_LAYOUT:
        names = [c.get('name') if isinstance(c, dict) else c for c in header['columns']]
        try:
            layout = layout_from_header(header)
            if names != list(layout.mem_names):     # rows already in a file layout (rewritten by a tool)
                return header, rows
            t0 = float(header.get('log_t0', rows[0, 0] if len(rows) else 0.0))
            rows = layout.to_file(rows, t0)
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as e:
            raise LogFormatError('{}: a log of memory rows without a valid description of its rows (core, '
                                 'polarities, fixed-point format, encoder zeros, start time): {!r}'.format(path, e))
        header['stored_columns'] = header['columns']
        header['columns'] = columns_header(layout.columns)
    return header, rows


def write_log(path, header, rows, columns):
    """Write a whole log at once (tests, the identify log): header, then rows (an n x ncols array,
    or an iterable of such blocks) of these (name, unit) columns, in the container of
    tipbot_fw.record.container."""
    container.write_log(path, header, rows, columns)
