"""Run log: per-tick rows in a preallocated buffer, written once at the end (docs/log-format.md).

Python 3.5-safe; the reader (read_log) is what host tools use.
"""
import json
import os
import struct
import time
import zlib

import numpy as np

MAGIC = b'TIPBLOG\n'
FORMAT_VERSION = 1
_COUNTS = struct.Struct('<IIIQ')   # format_version, header_len, ncols, nrows
_CRC = struct.Struct('<I')

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


class LogBuffer(object):
    """Preallocated rows; a ring when a run outlives it (the newest rows are kept).

    Tick k's row is packed (struct, little-endian float64, in-memory layout) into the
    bytearray `data` at byte offset (k % capacity) * MEM_ROW_BYTES; `mem` is a numpy view of the
    same memory. The loop keeps `count` (rows ever stored).
    """

    def __init__(self, capacity):
        self.capacity = int(capacity)
        self.data = bytearray(self.capacity * MEM_ROW_BYTES)
        self.mem = np.frombuffer(self.data, dtype='<f8').reshape(self.capacity, MEM_COLUMNS)
        self.count = 0
        self.t0 = 0.0       # the clock at the start of the first tick (set by the loop)

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


class LogFormatError(ValueError):
    """The file is not a complete, intact tipbot log; the message says what is wrong."""


def write_log(path, header, rows, nrows=None, columns=COLUMNS):
    """Write header (a JSON-able dict; 'columns' is added) and rows to path.

    columns: (name, unit) pairs; another list than the run log's COLUMNS makes another kind
    of log in the same container (tipbot_fw.identify), which the header must say.

    rows: an n x N_COLUMNS array; or, with nrows, an iterable of such blocks with nrows rows in
    all (LogBuffer.file_blocks: on the brick a full ring is then written with little memory
    beyond the buffer itself). Written to path + '.tmp' and renamed, so a reader never sees a
    half-written log.
    """
    if nrows is None:
        rows = np.asarray(rows)
        if rows.ndim != 2 or rows.shape[1] != len(columns):
            raise ValueError('log rows must be n x {}, got shape {}'.format(len(columns), rows.shape))
        nrows = rows.shape[0]
        blocks = [rows]
    else:
        blocks = rows
    header = dict(header)
    header['columns'] = columns_header(columns)
    header['format_version'] = FORMAT_VERSION
    text = json.dumps(header, sort_keys=True).encode('utf-8')
    counts = _COUNTS.pack(FORMAT_VERSION, len(text), len(columns), nrows)
    crc = zlib.crc32(text, zlib.crc32(counts))
    written = 0
    tmp = path + '.tmp'
    with open(tmp, 'wb') as f:
        f.write(MAGIC)
        f.write(counts)
        f.write(text)
        for block in blocks:
            body = np.ascontiguousarray(block, dtype='<f8')
            if body.size:
                data = memoryview(body).cast('B')
                crc = zlib.crc32(data, crc)
                f.write(data)
            written += len(body)
        f.write(_CRC.pack(crc & 0xffffffff))
        f.flush()
        os.fsync(f.fileno())
    if written != nrows:
        raise ValueError('log rows: {} written, {} announced'.format(written, nrows))
    os.rename(tmp, path)


def read_log(path):
    """-> (header dict, rows as an n x ncols float64 array). LogFormatError if not intact."""
    with open(path, 'rb') as f:
        data = f.read()
    pre = len(MAGIC) + _COUNTS.size
    if not data.startswith(MAGIC) and not MAGIC.startswith(data):
        raise LogFormatError('{}: not a tipbot log (bad magic bytes)'.format(path))
    if len(data) < pre:
        raise LogFormatError('{}: truncated: {} bytes, shorter than the fixed preamble'.format(path, len(data)))
    version, header_len, ncols, nrows = _COUNTS.unpack_from(data, len(MAGIC))
    if version != FORMAT_VERSION:
        raise LogFormatError('{}: log format version {} is not supported (this reader: {})'.format(
            path, version, FORMAT_VERSION))
    body_start = pre + header_len
    body_len = nrows * ncols * 8
    expected = body_start + body_len + _CRC.size
    if len(data) < expected:
        raise LogFormatError('{}: truncated: {} bytes, expected {} ({} rows of {} columns)'.format(
            path, len(data), expected, nrows, ncols))
    if len(data) > expected:
        raise LogFormatError('{}: {} unexpected bytes after the end of the log'.format(path, len(data) - expected))
    (crc,) = _CRC.unpack_from(data, expected - _CRC.size)
    actual = zlib.crc32(memoryview(data)[len(MAGIC):expected - _CRC.size]) & 0xffffffff
    if crc != actual:
        raise LogFormatError('{}: corrupted: CRC32 is {:08x}, expected {:08x}'.format(path, actual, crc))
    try:
        header = json.loads(data[pre:body_start].decode('utf-8'))
    except (ValueError, UnicodeError) as e:
        raise LogFormatError('{}: header is not valid JSON: {}'.format(path, e))
    if len(header.get('columns', ())) != ncols:
        raise LogFormatError('{}: header lists {} columns, body has {}'.format(
            path, len(header.get('columns', ())), ncols))
    rows = np.frombuffer(data, dtype='<f8', count=nrows * ncols, offset=body_start)
    return header, rows.reshape(nrows, ncols).astype(float)
