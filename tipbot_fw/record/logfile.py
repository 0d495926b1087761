"""Run log: the rows of each control core (their layout in memory and the columns of the file),
per-tick rows in a preallocated ring, written to the file in chunks in the loop's slack
(docs/log-format.md). The container (records, CRCs, reading a log cut short) is
tipbot_fw.record.container.

Two row layouts, one per core (tipbot_fw.cores.core): DetectorRows (the paper's detector: the floats
the core computes) and KalmanRows (the Kalman core: raw readings and the integer state, packed
once). Each has its memory row (mem_names, row_bytes, flags_index), the file's columns and
to_file(), which makes the second from the first; the file stores the memory rows as they are
and read_log() converts them, knowing the layout from the log's header (layout_from_header).

Python 3.5-safe; the reader (read_log) is what host tools use.
"""
import os
import struct
import time

import numpy as np

from tipbot_fw.cores import fixedpoint
from tipbot_fw.record import container
from tipbot_fw.record.container import FORMAT_VERSION, MAGIC, LogFormatError, LogWriteError, LogWriter  # noqa: F401

STATE_NAMES = ('d_r', 'd_l', 'th1', 'th2', 'th3', 'd_r_dot', 'd_l_dot', 'th1_dot', 'th2_dot', 'th3_dot')
STATE_UNITS = ('m', 'm', 'rad', 'rad', 'rad', 'm/s', 'm/s', 'rad/s', 'rad/s', 'rad/s')
INPUT_NAMES = ('r', 'l', 'th1', 'th2', 'th3')
ACTUATED_NAMES = ('r', 'l', 'th2', 'th3')

# The detector core's file layout (docs/log-format.md).
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
# copies (tipbot_fw.cores.core): duties are the device's (polarity applied), dcmd are the commands
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
SATURATION_BITS = 1 | 2 | 4 | 8
# The bits from SKIP_SHIFT on: the whole periods the loop missed after this tick (a stall), which
# the core predicted through (its skip(); the replay does the same)
SKIP_SHIFT = 7
SKIP_MAX = (1 << 20) - 1
# After this tick the loop kept the law's integrators within their limit (KalmanCore.wind_down),
# which the replay does at the same place; above the skipped periods' bits
WOUND_DOWN = 1 << 27


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


class DetectorRows(object):
    """The detector core's log row (tipbot_fw.cores.detector_core): MEM_NAMES in memory, COLUMNS in the
    file (to_file_layout)."""
    estimator = 'detector'
    mem_names = MEM_NAMES
    row_bytes = MEM_ROW_BYTES
    flags_index = MEM_FLAGS
    columns = COLUMNS
    column_names = COLUMN_NAMES
    col = staticmethod(col)

    def __init__(self, polarity):
        self.polarity = tuple(polarity)

    def header(self):
        """What a reader needs to know of this layout, for the log's header."""
        return {'estimator': self.estimator}

    @classmethod
    def from_header(cls, header):
        return cls([header['config']['polarity'][r] for r in ('right_wheel', 'left_wheel', 'joint2', 'joint3')])

    def to_file(self, mem_rows, t0=0.0):
        return to_file_layout(mem_rows, self.polarity, t0)


def kalman_columns(state_names, state_units):
    """(name, unit) of the Kalman core's file columns for the filter's states."""
    return ([('time_s', 's'), ('tick_s', 's'), ('enc_r', 'count'), ('enc_l', 'count'),
             ('enc_2', 'count'), ('enc_3', 'count'), ('gyro_angle', 'deg'), ('gyro_rate', 'deg/s'),
             ('battery_v', 'V'), ('flags', 'bits'),
             ('duty_r', '%'), ('duty_l', '%'), ('duty_2', '%'), ('duty_3', '%')]
            + [('xi_' + s, u) for s, u in zip(state_names, state_units)])


# The Kalman core's drive reference (tipbot_fw.cores.kalman, tipbot_fw.drive.plan): the file's columns
# after the state's; a log of a firmware before it has none.
REFERENCE_COLUMNS = (('ref_d_r', 'm'), ('ref_d_l', 'm'), ('ref_v_r', 'm/s'), ('ref_v_l', 'm/s'),
                     ('ref_a_r', 'm/s^2'), ('ref_a_l', 'm/s^2'))


class KalmanRows(object):
    """The Kalman core's log row (tipbot_fw.cores.kalman; docs/log-format.md). In memory: the two clock
    readings, battery_v, flags, gyro_angle as float64, then int64s: the duties, the carried state
    xi (xi_j 2^q_j: q, the state_exponents of tipbot_fw.cores.fixedpoint) and the product's inputs
    (the wheels' count changes, the four counts from their zeros, the gyro's raw rate): one copy
    of the core's integer vector, and the drive reference's integers (has_reference; ref_lsb: SI
    per integer, set by the core). In the file: the raw counts, the duties, xi and the reference in SI.

    offsets: the encoder zeros (the first tick's counts), set by the core's first tick or read
    from the log; the file's enc_* columns are the counts from them plus them."""
    estimator = 'kalman'
    flags_index = 3
    ints_start = 5
    n_inputs = 7

    def __init__(self, state_names, state_units, state_exponents, offsets=None, has_reference=True,
                 ref_lsb=None):
        self.state_names = list(state_names)
        self.state_units = list(state_units)
        self.n = n = len(self.state_names)
        self.q = [int(e) for e in state_exponents]
        if len(self.q) != n:
            raise ValueError('{} state exponents for {} states'.format(len(self.q), n))
        self.state_lsb = np.array([2.0 ** -e for e in self.q])
        self.mem_names = (['t_start', 't_written', 'battery_v', 'flags', 'gyro_angle']
                          + ['duty_r', 'duty_l', 'duty_2', 'duty_3'] + ['xi_' + s for s in self.state_names]
                          + ['dcount_r', 'dcount_l', 'rel_r', 'rel_l', 'rel_2', 'rel_3', 'gyro_rate'])
        self.has_reference = has_reference
        self.ref_lsb = ref_lsb
        self.columns = kalman_columns(self.state_names, self.state_units)
        if has_reference:       # after the product's constant input (tipbot_fw.cores.kalman)
            self.mem_names += ['one'] + [name for name, _ in REFERENCE_COLUMNS]
            self.columns += list(REFERENCE_COLUMNS)
        self.row_bytes = 8 * len(self.mem_names)
        self.column_names = [c[0] for c in self.columns]
        self.offsets = offsets

    @classmethod
    def for_gains(cls, kal):
        """The layout of a gains file's Kalman block (tipbot_fw.gains.KalmanGains)."""
        return cls(kal.state_names, kal.state_units, fixedpoint.state_exponents(kal.state_bounds))

    def header(self):
        """What a reader needs to know of this layout, for the log's header (the encoder zeros
        follow with the first rows)."""
        doc = {'estimator': self.estimator, 'state_names': self.state_names, 'state_units': self.state_units,
               'fixed_point': {'state_exponents': self.q}}
        if self.has_reference:
            doc['reference'] = {'columns': [name for name, _ in REFERENCE_COLUMNS], 'lsb': self.ref_lsb}
        return doc

    @classmethod
    def from_header(cls, header):
        names, units, q = header['state_names'], header['state_units'], header['fixed_point']['state_exponents']
        offsets = header.get('encoder_offsets')
        if not (isinstance(names, list) and isinstance(units, list) and len(names) == len(units)
                and all(isinstance(s, str) for s in names + units)):
            raise ValueError('state_names and state_units must be lists of names of the same length')
        if not (isinstance(q, list) and all(isinstance(e, int) and -64 <= e <= 128 for e in q)):
            raise ValueError('fixed_point.state_exponents must be a list of small integers')
        if offsets is not None and not (isinstance(offsets, list) and len(offsets) == 4
                                        and all(isinstance(z, int) and abs(z) < 2 ** 53 for z in offsets)):
            raise ValueError('encoder_offsets must be 4 integers')
        ref = header.get('reference')
        if ref is not None:
            lsb = ref.get('lsb') if isinstance(ref, dict) else 0
            # lsb null: a header written before the core was made (a start refused, no rows)
            if not (isinstance(ref, dict) and ref.get('columns') == [name for name, _ in REFERENCE_COLUMNS]
                    and (lsb is None or (isinstance(lsb, list) and len(lsb) == len(REFERENCE_COLUMNS)
                                         and all(isinstance(v, float) for v in lsb)))):
                raise ValueError('reference must name the columns {} and their lsb (numbers, or null)'.format(
                    [name for name, _ in REFERENCE_COLUMNS]))
            return cls(names, units, q, offsets, True, lsb)
        return cls(names, units, q, offsets, False)

    def to_file(self, mem_rows, t0=0.0):
        """In-memory rows (a float64 view, k x len(mem_names)) -> file rows (float64)."""
        mem = np.ascontiguousarray(mem_rows, dtype='<f8')
        ints = mem[:, self.ints_start:].view('<i8')
        n = self.n
        out = np.zeros((len(mem), len(self.columns)))
        out[:, 0] = mem[:, 0] - t0
        out[:, 1] = mem[:, 1] - mem[:, 0]
        zeros = self.offsets or (0, 0, 0, 0)
        for j in range(4):
            out[:, 2 + j] = ints[:, 4 + n + 2 + j] + zeros[j]
        out[:, 6] = mem[:, 4]
        out[:, 7] = ints[:, 4 + n + 6]
        out[:, 8] = mem[:, 2]
        out[:, 9] = mem[:, 3]
        out[:, 10:14] = ints[:, 0:4]
        out[:, 14:14 + n] = ints[:, 4:4 + n] * self.state_lsb[None, :]
        if self.has_reference:
            nr = len(REFERENCE_COLUMNS)
            base = 4 + n + self.n_inputs + 1
            out[:, 14 + n:14 + n + nr] = ints[:, base:base + nr] * np.array(
                self.ref_lsb or [0.0] * nr)[None, :]
        return out

    def reference_ints(self, file_row):
        """The reference's integers of a file row (the inverse of to_file's SI, exact)."""
        base = self.col('ref_d_r')
        return [int(round(file_row[base + i] / lsb)) if lsb else 0 for i, lsb in enumerate(self.ref_lsb)]

    def col(self, name):
        return self.column_names.index(name)


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


def columns_header(columns=COLUMNS):
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


def write_log(path, header, rows, nrows=None, columns=COLUMNS):
    """Write a whole log at once (tests, the identify log): header, then rows (an n x ncols array,
    or with nrows an iterable of such blocks), in the container of tipbot_fw.record.container."""
    container.write_log(path, header, rows, columns)
