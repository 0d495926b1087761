"""Run log: the columns, per-tick rows in a preallocated ring, written to the file in chunks in
the loop's slack (docs/log-format.md). The container (records, CRCs, reading a log cut short)
is tipbot_fw.logcontainer.

Python 3.5-safe; the reader (read_log) is what host tools use.
"""
import os
import struct
import time

import numpy as np

from tipbot_fw import logcontainer
from tipbot_fw.logcontainer import FORMAT_VERSION, MAGIC, LogFormatError, LogWriteError, LogWriter  # noqa: F401

STATE_NAMES = ('d_r', 'd_l', 'th1', 'th2', 'th3', 'd_r_dot', 'd_l_dot', 'th1_dot', 'th2_dot', 'th3_dot')
STATE_UNITS = ('m', 'm', 'rad', 'rad', 'rad', 'm/s', 'm/s', 'rad/s', 'rad/s', 'rad/s')
INPUT_NAMES = ('r', 'l', 'th1', 'th2', 'th3')
ACTUATED_NAMES = ('r', 'l', 'th2', 'th3')

# File layout (docs/log-format.md).
COLUMNS = ([('time_s', 's'), ('tick_s', 's'),
            ('enc_r', 'count'), ('enc_l', 'count'), ('enc_2', 'count'), ('enc_3', 'count'),
            ('gyro_angle', 'deg'), ('gyro_rate', 'deg/s'),
            ('battery_v', 'V'), ('gyro_bias', 'deg/s')]
           + [('y_' + n, u) for n, u in zip(STATE_NAMES, STATE_UNITS)]
           + [('xt_' + n, u) for n, u in zip(STATE_NAMES, STATE_UNITS)]
           + [('w_' + n, 'V') for n in INPUT_NAMES]
           + [('u_' + n, 'V') for n in INPUT_NAMES]
           + [('u_cmd_' + n, 'V') for n in INPUT_NAMES]
           + [('duty_r', '%'), ('duty_l', '%'), ('duty_2', '%'), ('duty_3', '%'),
              ('flags', 'bits')])
COLUMN_NAMES = [c[0] for c in COLUMNS]
N_COLUMNS = len(COLUMNS)


def col(name):
    return COLUMN_NAMES.index(name)


TIME = col('time_s')
TICK = col('tick_s')
ENC = col('enc_r')          # 4 columns
GYRO = col('gyro_angle')    # angle, rate
BATTERY = col('battery_v')
BIAS = col('gyro_bias')
Y = col('y_d_r')            # 10 columns each
XT = col('xt_d_r')
W = col('w_r')              # 5 columns each
U = col('u_r')
U_CMD = col('u_cmd_r')
DUTY = col('duty_r')        # 4 columns
FLAGS = col('flags')

# In-memory row layout, chosen so that the core fills a row with one struct pack and two byte
# copies (tipbot_fw.core): duties are the device's (polarity applied), dcmd are the commands
# before saturation in the same units, and the always-zero th1 inputs are left out.
# to_file_layout() derives the file's volts from them (u = polarity * duty * battery_v / 100)
# and the times (the loop stores clock readings, cheaper than differences).
MEM_NAMES = (['t_start', 't_written', 'enc_r', 'enc_l', 'enc_2', 'enc_3', 'gyro_angle', 'gyro_rate',
              'battery_v', 'gyro_bias', 'flags', 'duty_r', 'duty_l', 'duty_2', 'duty_3']
             + ['y_' + n for n in STATE_NAMES] + ['xt_' + n for n in STATE_NAMES]
             + ['w_' + n for n in ACTUATED_NAMES] + ['dcmd_' + n for n in ACTUATED_NAMES])
MEM_COLUMNS = len(MEM_NAMES)
MEM_ROW_BYTES = 8 * MEM_COLUMNS
MEM_ENC = MEM_NAMES.index('enc_r')
MEM_FLAGS = MEM_NAMES.index('flags')
MEM_DUTY = MEM_NAMES.index('duty_r')   # duties (4), y (10): one copy of the core's v[10:24]
MEM_Y = MEM_NAMES.index('y_d_r')
MEM_Z = MEM_NAMES.index('xt_d_r')      # x~ (10), w^ (4), dcmd (4): one copy of the core's z
TIMES = struct.Struct('<2d')           # the clock at the tick's start and after its writes:
                                       # packed by the loop, made time_s and tick_s on writing
_COPIED = [(i, MEM_NAMES.index(n)) for i, n in enumerate(COLUMN_NAMES) if n in MEM_NAMES]
_DERIVED = [(col('u_' + n), MEM_NAMES.index('duty_' + d), k) for k, (n, d) in
            enumerate(zip(ACTUATED_NAMES, ('r', 'l', '2', '3')))] + \
           [(col('u_cmd_' + n), MEM_NAMES.index('dcmd_' + n), k) for k, n in enumerate(ACTUATED_NAMES)]

# flags bits
FLAG_BITS = {
    'sat_r': 1, 'sat_l': 2, 'sat_th2': 4, 'sat_th3': 8,   # duty limited (u_max_v or +-100 %)
    'overrun': 16,      # this tick's work ended after the next release
    'fall': 32,         # |th1| beyond limits.th1_rad: motors stopped in this tick
    'joint_limit': 64,  # |th2| or |th3| beyond its limit: motors stopped in this tick
}


def to_file_layout(mem_rows, polarity, t0=0.0):
    """In-memory rows (n x MEM_COLUMNS) -> file rows (n x N_COLUMNS); polarity: 4 of +1/-1,
    t0: the clock at the start of the first tick."""
    mem_rows = np.asarray(mem_rows, dtype=float)
    out = np.zeros((len(mem_rows), N_COLUMNS))
    for f, m in _COPIED:
        out[:, f] = mem_rows[:, m]
    out[:, TIME] = mem_rows[:, 0] - t0
    out[:, TICK] = mem_rows[:, 1] - mem_rows[:, 0]
    volts_per_duty = mem_rows[:, MEM_NAMES.index('battery_v')] / 100.0
    for f, m, k in _DERIVED:
        out[:, f] = polarity[k] * mem_rows[:, m] * volts_per_duty
    return out


# Rows a chunk of the file holds: written in the slack of one tick every CHUNK_ROWS ticks
# (0.25 s at 5 ms), so a crash or a power cut loses at most that much of what the file had
# been sent; the ring in memory holds RING_CHUNKS chunks, so a chunk may wait for a tick with
# slack (tipbot_fw.loop) without being overwritten.
CHUNK_ROWS = 50
RING_CHUNKS = 8


class LogBuffer(object):
    """Preallocated rows; a ring when a run outlives it.

    Tick k's row is packed (struct, little-endian float64, in-memory layout) into the
    bytearray `data` at byte offset (k % capacity) * MEM_ROW_BYTES; `mem` is a numpy view of the
    same memory. The loop keeps `count` (rows ever stored).

    With a ``writer`` (a tipbot_fw.logcontainer.LogWriter), the rows go to the file in chunks:
    flush() writes the rows not yet written (at most ``max_rows`` in all: the rest are counted,
    not recorded), so the ring needs only a few chunks; without one the ring keeps the newest
    ``capacity`` rows (bench, tests).
    """

    def __init__(self, capacity, writer=None, polarity=(1, 1, 1, 1), max_rows=None, chunk_rows=CHUNK_ROWS):
        self.capacity = int(capacity)
        self.data = bytearray(self.capacity * MEM_ROW_BYTES)
        self.mem = np.frombuffer(self.data, dtype='<f8').reshape(self.capacity, MEM_COLUMNS)
        self.count = 0
        self.t0 = 0.0       # the clock at the start of the first tick (set by the loop)
        self.writer = writer
        self.polarity = polarity
        self.max_rows = max_rows
        self.chunk_rows = chunk_rows
        self.flushed = 0    # rows sent to the writer (or dropped beyond max_rows)
        self.first_info = None  # () -> dict for an INFO record before the first rows (the zeros)

    @classmethod
    def for_file(cls, writer, polarity, max_rows, chunk_rows=CHUNK_ROWS):
        return cls(chunk_rows * RING_CHUNKS, writer, polarity, max_rows, chunk_rows)

    def flush(self, end=None):
        """Write the rows stored (``end`` of them: the loop's count during a run; else count) and
        not yet written, outside the ticks. Never raises."""
        end = self.count if end is None else end
        start = max(self.flushed, end - self.capacity)
        if self.writer is None or end <= start:
            return
        stop = end if self.max_rows is None else min(end, self.max_rows)
        if self.first_info is not None:
            info = self.first_info()
            info['log_t0'] = self.t0
            self.writer.info(info)
            self.first_info = None
        if stop > start:
            self.writer.rows_bytes(*self._block(start, stop))
        self.flushed = end

    def _block(self, start, stop):
        """The rows start..stop as the file stores them: the memory layout's bytes as they are
        (no conversion on the brick: read_log derives the file layout)."""
        p, q = (start % self.capacity) * MEM_ROW_BYTES, (stop - start) * MEM_ROW_BYTES
        end = p + q
        if end <= len(self.data):
            return self.data[p:end], stop - start
        return self.data[p:] + self.data[:end - len(self.data)], stop - start

    def not_recorded(self):
        """Rows stored but beyond max_rows (not in the file)."""
        return 0 if self.max_rows is None else max(0, self.count - self.max_rows)

    def first_tick(self):
        """Index of the tick of the oldest row kept."""
        return max(0, self.count - self.capacity)

    def kept(self):
        """Number of rows kept."""
        return min(self.count, self.capacity)

    def file_blocks(self, polarity, size=2048):
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
            yield to_file_layout(block, polarity, self.t0)

    def ordered(self, polarity):
        """-> (index of the first kept tick, all kept rows oldest first in the file layout)."""
        blocks = list(self.file_blocks(polarity))
        rows = np.concatenate(blocks) if blocks else np.zeros((0, N_COLUMNS))
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


def columns_header(columns=COLUMNS):
    return [{'name': n, 'unit': u} for n, u in columns]


# What a run's log file stores: the memory rows (MEM_NAMES), converted to COLUMNS when read.
STORED_LAYOUT = 'memory'
STORED_COLUMNS = [(n, '') for n in MEM_NAMES]


def open_run_log(path, reserve_rows):
    """A LogWriter for a run log: its rows are memory rows (LogBuffer.flush)."""
    return LogWriter(path, STORED_COLUMNS, reserve_rows, layout=STORED_LAYOUT)


def read_log(path):
    """-> (header, rows in the file layout COLUMNS). A run log whose file stores memory rows
    (format 2) is converted here with its own configuration's polarities and its log_t0, so
    every reader sees the columns of docs/log-format.md. LogFormatError as logcontainer.read_log."""
    header, rows = logcontainer.read_log(path)
    names = [c.get('name') if isinstance(c, dict) else c for c in header['columns']]
    if header.get('layout') == STORED_LAYOUT and names == MEM_NAMES:
        try:
            pol = [header['config']['polarity'][r] for r in ('right_wheel', 'left_wheel', 'joint2', 'joint3')]
            t0 = float(header.get('log_t0', rows[0, 0] if len(rows) else 0.0))
        except (KeyError, TypeError, ValueError) as e:
            raise LogFormatError('{}: a log of memory rows without its polarities or start time: {!r}'.format(path, e))
        rows = to_file_layout(rows, pol, t0)
        header['stored_columns'] = header['columns']
        header['columns'] = columns_header(COLUMNS)
    return header, rows


def write_log(path, header, rows, nrows=None, columns=COLUMNS):
    """Write a whole log at once (tests, the identify log): header, then rows (an n x ncols array,
    or with nrows an iterable of such blocks), in the container of tipbot_fw.logcontainer."""
    logcontainer.write_log(path, header, rows, columns)
