"""The log file's container (docs/log-format.md): records that each check themselves, written
while the robot runs, so that a crash, a full disk or a power cut keeps what was written and
the file still reads. Generic over the columns the header declares (tipbot_fw.record.logfile has the
run log's columns, tipbot_fw.identify the identify log's). Python 3.5, numpy, standard library.

Format version 2::

    b"TIPBLOG\\n"  u32 format version (2)
    record*       u32 tag | u32 payload length | u32 CRC-32 of tag and length | payload | u32 CRC-32 of payload

Tags: HEAD (the JSON header, first and once), INFO (JSON merged into the header: what a run
learns after its start, such as the calibration and the encoder zeros), ROWS (u64 index of the
first row, u32 row count, then the rows: little-endian float64, ``len(columns)`` a row), TAIL
(JSON merged into the header: how the run ended; last). The file is preallocated for the rows
a run can keep (``posix_fallocate``: a full disk is found before the motors move) and cut to its
end when it is closed.

Bounded logs (LogWriter's ``keep``: head rows, ring slots, slot rows): the first ``head`` rows go
in order as above (the head: calibration, start, first seconds). The header's ``ring`` says
where the rest goes: ``slots`` fixed-size slots from byte ``start_byte`` (a page boundary after
the room the records before it can take, so that no damage to those reaches the ring, and back);
chunk c of the rows after the head (rows head + c * slot_rows onwards) is one ROWS record
written over slot c mod slots, so the slots hold the run's last chunks and the file never
grows. The TAIL follows the last slot once the ring is used. Each slot's record carries its
first row index and its CRC: the reader takes every intact slot whose index fits its place,
orders them, keeps the newest ``slots`` chunks and drops a torn one (a write a crash or a power
cut cut short) or a stale one; what is missing between the parts is reported as gaps.

Reading (read_log): every record is checked. The intact part of a log that does not end with
its TAIL (a crash or a power cut, or a write that failed: the file ends inside a record, or in
zeros where the preallocated space was never written, or without a TAIL) is returned, with
``header['incomplete']`` saying where and why it ends; a damaged record followed by intact
ones (a flipped bit, not an end) is refused. Logs of format version 1 (one CRC over the whole
file, written at the end of a run) are still read.
"""
import json
import os
import struct
import zlib

import numpy as np

from tipbot_fw import fields
from tipbot_fw.vocabulary import LOG_FORMAT_VERSION

MAGIC = b'TIPBLOG\n'
FORMAT_VERSION = LOG_FORMAT_VERSION
READ_VERSIONS = (1, 2)
HEAD, INFO, ROWS, TAIL = b'HEAD', b'INFO', b'ROWS', b'TAIL'
TAGS = (HEAD, INFO, ROWS, TAIL)
_U32 = struct.Struct('<I')
_REC = struct.Struct('<4sII')          # tag, payload length, CRC of both
_ROWS = struct.Struct('<QI')           # first row index, row count
_OVERHEAD = _REC.size + _ROWS.size + 4  # a ROWS record's bytes beyond its rows
_V1_COUNTS = struct.Struct('<IIIQ')    # version 1: format_version, header_len, ncols, nrows
RESERVE_EXTRA_BYTES = 256 * 1024       # header, INFO and TAIL records, beyond the rows
MAX_JSON_BYTES = 16 * 1024 * 1024


class LogFormatError(ValueError):
    """The file is not a tipbot log, or a damaged one; the message says what is wrong."""


class LogWriteError(OSError):
    """The log cannot be opened or reserved (the path, the disk); raised before any motor moves."""


def _crc(data, start=0):
    return zlib.crc32(data, start) & 0xffffffff


def _json_bytes(doc):
    return json.dumps(doc, sort_keys=True, allow_nan=False).encode('utf-8')


class LogWriter(object):
    """A log written record by record. Opening checks the path and reserves room for
    ``reserve_rows`` rows, or for what ``keep`` keeps (LogWriteError if either fails: nothing
    has run yet). After that nothing raises: a failed write (a full disk, an I/O error) is kept
    in ``failed``, the later records are skipped, and what was written before still reads.

    keep: None (every row, in order) or (head, slots, slot_rows): the first ``head`` rows in
    order, then a ring of ``slots`` slots of ``slot_rows`` rows keeping the last ones (module
    docstring; slots 0: the first ``head`` rows only). Rows given after the head must start at a
    chunk boundary (head + a multiple of slot_rows): tipbot_fw.record.logfile.LogBuffer flushes so."""

    def __init__(self, path, columns, reserve_rows=0, layout=None, keep=None):
        self.path = path
        self.layout = layout
        self.ncols = len(columns)
        self.columns = [{'name': n, 'unit': u} for n, u in columns]
        self.rows_written = 0   # rows given (the next row's index), kept or not
        self.failed = None
        self.lost = None        # set by close(): the file was taken away during the run
        self.closed = False
        self.head, self.slots, self.slot_rows = keep if keep is not None else (None, 0, 1)
        self.slot_bytes = _OVERHEAD + 8 * self.ncols * self.slot_rows
        self.ring_start = None  # byte offset of slot 0
        self.slot_held = [None] * self.slots   # (first row, count) in each slot
        self.dropped = 0        # rows given and not kept (beyond the head, overwritten in the ring)
        self.ring_entered = False
        if keep is not None:
            reserve_rows = self.head
        if self.slots:      # slot 0 at a fixed byte, on a page, after the room for the records before
            first = RESERVE_EXTRA_BYTES + self.head * 8 * self.ncols + (self.head // self.slot_rows + 2) * _OVERHEAD
            self.ring_start = -(-first // 4096) * 4096
        try:
            self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as e:
            raise LogWriteError(e.errno, 'cannot write the log {}: {}'.format(path, e.strerror or e))
        self.pos = 0
        reserve = RESERVE_EXTRA_BYTES + int(reserve_rows) * 8 * self.ncols
        if self.slots:
            reserve = self.ring_start + self.slots * self.slot_bytes + RESERVE_EXTRA_BYTES // 4   # the TAIL after
        try:
            if hasattr(os, 'posix_fallocate'):
                try:
                    os.posix_fallocate(self.fd, 0, reserve)
                except OSError as e:
                    if e.errno not in (95, 22):      # EOPNOTSUPP, EINVAL: a file system without it
                        raise
            self._write(MAGIC + _U32.pack(FORMAT_VERSION))
        except OSError as e:
            os.close(self.fd)
            try:
                os.unlink(path)
            except OSError:
                pass
            raise LogWriteError(e.errno, 'no room for the log {} ({:.1f} MB for {} rows): {}'.format(
                path, reserve / 1e6, reserve_rows + self.slots * self.slot_rows, e.strerror or e))

    def _write(self, data, at=None):
        pos = self.pos if at is None else at
        n = os.pwrite(self.fd, data, pos)
        if n != len(data):
            raise OSError(28, 'short write ({} of {} bytes)'.format(n, len(data)))
        if at is None:
            self.pos += n

    def _record(self, tag, payload, at=None):
        if self.failed is not None or self.closed:
            return False
        if at is None and self.slots and self.pos + len(payload) + 16 > self.ring_start and tag != TAIL:
            self.failed = 'the log\'s records before its ring outgrew their room ({} bytes)'.format(self.ring_start)
            return False
        head = tag + _U32.pack(len(payload))
        try:
            self._write(head + _U32.pack(_crc(head)) + bytes(payload) + _U32.pack(_crc(payload)), at)
        except OSError as e:
            self.failed = 'writing the log failed after {} rows: {}'.format(self.rows_written, e.strerror or e)
            return False
        return True

    def header(self, doc):
        doc = dict(doc)
        doc['columns'] = self.columns
        doc['format_version'] = FORMAT_VERSION
        if self.layout is not None:
            doc['layout'] = self.layout
        doc.pop('ring', None)       # (a rewritten log's rows are in order: it has no ring)
        if self.slots:
            doc['ring'] = {'head_rows': self.head, 'slot_rows': self.slot_rows, 'slots': self.slots,
                           'slot_bytes': self.slot_bytes, 'start_byte': self.ring_start}
        return self._record(HEAD, _json_bytes(doc))

    def info(self, doc):
        return self._record(INFO, _json_bytes(doc))

    def rows(self, block):
        """Append rows (n x ncols, any float array). -> written or not."""
        body = np.ascontiguousarray(block, dtype='<f8')
        if body.ndim != 2 or body.shape[1] != self.ncols:
            raise ValueError('log rows must be n x {}, got shape {}'.format(self.ncols, body.shape))
        return self.rows_bytes(body.tobytes(), len(body))

    def rows_bytes(self, data, count):
        """Append ``count`` rows given as their bytes (little-endian float64, ncols a row): one
        ROWS record in the head, one per chunk in the ring. What the control loop's slack can
        afford (no conversion, one copy of the bytes into the record). -> written or not."""
        width = 8 * self.ncols
        if len(data) != width * count:
            raise ValueError('{} bytes are not {} rows of {} columns'.format(len(data), count, self.ncols))
        first = self.rows_written
        if self.head is None or first + count <= self.head:
            ok = self._record(ROWS, _ROWS.pack(first, count) + data)
            self.rows_written = first + count
            return ok
        data = memoryview(data)
        n = max(0, self.head - first)
        ok = self._record(ROWS, _ROWS.pack(first, n) + data[:n * width]) if n else True
        self.rows_written = first + count
        if not self.slots:
            self.dropped += count - n
            return ok
        self.ring_entered = True
        while n < count and ok:
            r = first + n
            c = (r - self.head) // self.slot_rows
            m = min(count - n, self.head + (c + 1) * self.slot_rows - r)
            slot = c % self.slots
            ok = self._record(ROWS, _ROWS.pack(r, m) + data[n * width:(n + m) * width],
                              self.ring_start + slot * self.slot_bytes)
            held = self.slot_held[slot]
            if held is not None and held[0] != r:
                self.dropped += held[1]
            self.slot_held[slot] = (r, m)
            n += m
        return ok

    def not_kept(self):
        """-> [(first, last)] the row indices given and not kept (a long run's middle)."""
        if self.head is None or self.rows_written <= self.head:
            return []
        kept = [h[0] for h in self.slot_held if h is not None]
        first_kept = min(kept) if kept else self.rows_written
        return [(self.head, first_kept - 1)] if first_kept > self.head else []

    def close(self, trailer):
        """TAIL (after the ring's last slot, if any), cut the file to its end, fsync, close.
        Never raises; -> None or the problem."""
        if self.closed:
            return self.lost or self.failed
        if self.ring_entered:
            self.pos = self.ring_start + self.slots * self.slot_bytes
        self._record(TAIL, _json_bytes(trailer))
        self.closed = True
        try:
            os.ftruncate(self.fd, self.pos)
            os.fsync(self.fd)
        except OSError as e:
            if self.failed is None:
                self.failed = 'finishing the log failed: {}'.format(e.strerror or e)
        self.lost = self._taken_away()
        try:
            os.close(self.fd)
        except OSError:
            pass
        return self.lost or self.failed

    def _taken_away(self):
        """-> why the file at ``path`` is not this run's log any more, or None. Another process
        may unlink, replace or truncate it while the run writes: the writes then land in a file
        nobody sees, or after a hole where the header was."""
        try:
            mine = os.fstat(self.fd)
        except OSError:
            return None     # cannot tell: the writes' own errors are in ``failed``
        try:
            there = os.stat(self.path)
        except OSError:
            there = None
        if mine.st_nlink == 0:
            return 'the file was {} during the run (by another process): the log is lost'.format(
                'deleted' if there is None else 'replaced by another file')
        if there is None:
            return 'the file was moved away during the run (by another process): it is not at this path'
        if (there.st_dev, there.st_ino) != (mine.st_dev, mine.st_ino):
            return 'the file was moved away and another put at its path during the run (by another process)'
        try:
            with open(self.path, 'rb') as f:
                start = f.read(len(MAGIC))
        except OSError:
            return None
        if start != MAGIC:
            return 'the file was cut short during the run (by another process): its start is gone and it does ' \
                'not read'
        return None


def write_log(path, header, rows, columns):
    """A whole log at once (identify logs, tests): header, the rows (n x ncols, or an iterable of
    such blocks) and a TAIL that holds nothing more. Raises what fails."""
    blocks = [rows] if isinstance(rows, np.ndarray) else rows
    w = LogWriter(path, columns)
    w.header(header)
    for block in blocks:
        if len(block):
            w.rows(block)
    problem = w.close({})
    if problem:
        raise OSError(problem)


# ------------------------------------------------------------------------------ reading
def _parse_json(data, path, what):
    try:
        doc = fields.loads(bytes(data))
    except fields.JsonProblem as e:
        raise LogFormatError('{}: {} {}'.format(path, what, e))
    if not isinstance(doc, dict):
        raise LogFormatError('{}: {} is not a JSON object'.format(path, what))
    return doc


def read_log(path):
    """-> (header dict, rows as an n x ncols float64 array). LogFormatError if the file is no
    tipbot log or is damaged; a log cut short is returned with header['incomplete']."""
    with open(path, 'rb') as f:
        data = f.read()
    pre = len(MAGIC) + 4
    if not data.startswith(MAGIC):
        if MAGIC.startswith(data):
            raise LogFormatError('{}: truncated: {} bytes, shorter than the fixed preamble'.format(path, len(data)))
        raise LogFormatError('{}: not a tipbot log (bad magic bytes)'.format(path))
    if len(data) < pre:
        raise LogFormatError('{}: truncated: {} bytes, shorter than the fixed preamble'.format(path, len(data)))
    (version,) = _U32.unpack_from(data, len(MAGIC))
    if version == 1:
        return _read_v1(path, data)
    if version not in READ_VERSIONS:
        raise LogFormatError('{}: log format version {} is not supported (this reader: {})'.format(
            path, version, ', '.join(str(v) for v in READ_VERSIONS)))
    return _read_v2(path, data, pre)


def _read_v2(path, data, pos):
    size = len(data)
    header = None
    merged = {}
    blocks = []
    nrows = 0
    incomplete = None
    ended = False
    ring, limit = None, size        # a bounded log's records before its ring end at the ring
    while pos < min(size, limit):
        if ended:
            if not any(data[pos:limit]):
                break
            raise LogFormatError('{}: {} unexpected bytes after the end of the log'.format(path, min(size, limit) - pos))
        got = _record_at(path, data, pos, limit)
        if got is None:
            if ring is None:
                incomplete = 'the file ends in space reserved and never written, from byte {}'.format(pos)
            break                   # (before a ring: the room left for the first rows, unused)
        if isinstance(got, str):
            incomplete = got
            break
        tag, payload, end = got
        if header is None and tag != HEAD:
            raise LogFormatError('{}: corrupted: the first record is {}, not the header'.format(path, tag.decode('ascii')))
        if tag == HEAD:
            if header is not None:
                raise LogFormatError('{}: corrupted: a second header at byte {}'.format(path, pos))
            header = _parse_json(payload, path, 'header')
            ncols = _ncols(header, path)
            ring = _ring_of(header, ncols, end, path)
            limit = size if ring is None else ring[4]
        elif tag in (INFO, TAIL):
            merged.update(_parse_json(payload, path, 'record at byte {}'.format(pos)))
            ended = tag == TAIL
        else:
            if len(payload) < _ROWS.size:
                raise LogFormatError('{}: corrupted: ROWS record at byte {} too short'.format(path, pos))
            first, count = _ROWS.unpack_from(payload, 0)
            if first != nrows or len(payload) != _ROWS.size + 8 * count * ncols:
                raise LogFormatError('{}: corrupted: ROWS record at byte {} holds rows {}..{} of {} columns in {} '
                                     'bytes, expected row {} next'.format(path, pos, first, first + count, ncols,
                                                                          len(payload), nrows))
            blocks.append(np.frombuffer(payload, dtype='<f8', offset=_ROWS.size).reshape(count, ncols))
            nrows += count
        pos = end
    if header is None:
        raise LogFormatError('{}: truncated: {}'.format(path, incomplete or 'no header record'))
    chunks, torn = [], 0
    if ring is not None and not ended:      # (read even when the first rows end damaged)
        chunks, torn, ring_end = _read_ring(data, ring, ncols)
        if ring_end > size:
            incomplete = incomplete or 'the file ends inside the ring of the last rows, at byte {}'.format(size)
        else:
            got = _record_at(path, data, ring_end, size)
            if isinstance(got, str):
                incomplete = incomplete or got
            elif got is not None:
                tag, payload, end = got
                if tag != TAIL or any(data[end:]):
                    raise LogFormatError('{}: corrupted: a {} record after the ring, at byte {}, where the end record '
                                         'belongs'.format(path, tag.decode('ascii'), ring_end))
                merged.update(_parse_json(payload, path, 'record at byte {}'.format(ring_end)))
                ended = True
    if incomplete is None and not ended:
        incomplete = 'no trailer: the run did not finish writing its log'
    header.update(merged)
    if ring is not None:
        blocks += [c[2] for c in chunks]
        _describe_parts(header, nrows, chunks, torn)
        nrows += sum(c[1] for c in chunks)
    if incomplete is not None:
        header['incomplete'] = '{}; {} intact rows (a crash, a power cut or a full disk)'.format(incomplete, nrows)
    rows = np.concatenate(blocks).astype(float) if blocks else np.zeros((0, ncols))
    return header, rows


def _record_at(path, data, pos, limit):
    """The record at byte pos, ending by byte limit -> (tag, payload, end); None: zeros from pos
    to limit (space reserved and never written); a string: why the log ends there (cut short,
    or its last record damaged). LogFormatError for a damaged record with data after it."""
    size = len(data)
    if size - pos < _REC.size:
        return 'the file ends inside a record header at byte {}'.format(pos)
    tag, n, hcrc = _REC.unpack_from(data, pos)
    if _crc(data[pos:pos + 8]) != hcrc or tag not in TAGS:
        if not any(data[pos:limit]):
            return None
        raise LogFormatError('{}: corrupted: bad record header at byte {}'.format(path, pos))
    end = pos + _REC.size + n + 4
    if end > min(size, limit):
        if end <= size:
            raise LogFormatError('{}: corrupted: the {} record at byte {} runs into the ring of the last rows'.format(
                path, tag.decode('ascii'), pos))
        return 'the file ends inside a {} record at byte {} ({} of its {} bytes)'.format(
            tag.decode('ascii'), pos, size - pos, end - pos)
    payload = memoryview(data)[pos + _REC.size:end - 4]
    (pcrc,) = _U32.unpack_from(data, end - 4)
    if _crc(payload) != pcrc:
        if end == size or not any(data[end:limit]):
            return 'its last record ({} at byte {}) is damaged'.format(tag.decode('ascii'), pos)
        raise LogFormatError('{}: corrupted: CRC32 of the {} record at byte {} is {:08x}, expected {:08x}'.format(
            path, tag.decode('ascii'), pos, _crc(payload), pcrc))
    return tag, payload, end


def _ring_of(header, ncols, after, path):
    """A bounded log's ring (header['ring']) -> (head rows, rows a slot, slots, bytes a slot,
    byte of slot 0), or None; LogFormatError if it does not describe a ring of these rows."""
    doc = header.get('ring')
    if doc is None:
        return None
    keys = ('head_rows', 'slot_rows', 'slots', 'slot_bytes', 'start_byte')
    if not isinstance(doc, dict):
        raise LogFormatError('{}: header field ring must be an object, got {!r}'.format(path, doc))
    ring = tuple(doc.get(k) for k in keys)
    if not (all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2 ** 40 for v in ring)
            and ring[1] > 0 and ring[2] > 0 and ring[3] == _OVERHEAD + 8 * ncols * ring[1] and ring[4] >= after):
        raise LogFormatError('{}: header field ring must give {} of a ring of slots of {} columns after the header, '
                             'got {!r}'.format(path, ', '.join(keys), ncols, doc))
    return ring


def _read_ring(data, ring, ncols):
    """The ring's slots -> ([(first row, count, rows)] oldest first, slots dropped (torn,
    damaged or misplaced), the byte after the last slot)."""
    head, slot_rows, slots, slot_bytes, start = ring
    found = []
    torn = 0
    for s in range(slots):
        p = start + s * slot_bytes
        if p >= len(data):
            break
        rec = data[p:p + slot_bytes]
        if not any(rec):
            continue                     # never written
        try:                             # the record as anywhere else; any fault makes it torn
            got = _record_at('', rec, 0, len(rec))
        except LogFormatError:
            got = None
        ok = isinstance(got, tuple) and got[0] == ROWS and len(got[1]) >= _ROWS.size
        if ok:
            payload = got[1]
            first, count = _ROWS.unpack_from(payload, 0)
            ok = (0 < count <= slot_rows and len(payload) == _ROWS.size + 8 * ncols * count and first >= head
                  and (first - head) % slot_rows == 0 and (first - head) // slot_rows % slots == s)
        if ok:
            found.append((first, count, np.frombuffer(payload, dtype='<f8', offset=_ROWS.size).reshape(count, ncols)))
        else:
            torn += 1
    found.sort(key=lambda c: c[0])
    if found:   # a slot a failed write left behind holds a chunk older than the ring's span
        newest = found[-1][0]
        found = [c for c in found if c[0] > newest - slots * slot_rows]
    return found, torn, start + slots * slot_bytes


def _describe_parts(header, head_rows, chunks, torn):
    """header['segments']: [first tick, rows] of each run of consecutive rows, in file order;
    header['not_kept']: [first, last] ticks before, between and (up to the run's last tick)
    after them that the log does not hold."""
    first_tick = header.get('first_tick', 0)
    first_tick = first_tick if isinstance(first_tick, int) and not isinstance(first_tick, bool) else 0
    segments = [[first_tick, head_rows]] if head_rows else []
    for first, count, _ in chunks:
        if segments and segments[-1][0] + segments[-1][1] == first_tick + first:
            segments[-1][1] += count
        else:
            segments.append([first_tick + first, count])
    gaps = [[a[0] + a[1], b[0] - 1] for a, b in zip(segments, segments[1:])]
    if segments and segments[0][0] > first_tick:       # a ring without a head
        gaps.insert(0, [first_tick, segments[0][0] - 1])
    ticks = header.get('ticks')
    end = segments[-1][0] + segments[-1][1] if segments else first_tick
    if isinstance(ticks, int) and not isinstance(ticks, bool) and ticks > end:
        gaps.append([end, ticks - 1])
    header['segments'] = segments
    header['not_kept'] = gaps
    if torn:
        header['ring_dropped_chunks'] = torn


def _ncols(header, path):
    cols = header.get('columns')
    if not isinstance(cols, list) or not cols:
        raise LogFormatError('{}: header has no list of columns'.format(path))
    return len(cols)


def _read_v1(path, data):
    """Format version 1: counts, header, body and one CRC-32 over them, written at the end."""
    pre = len(MAGIC) + _V1_COUNTS.size
    if len(data) < pre:
        raise LogFormatError('{}: truncated: {} bytes, shorter than the fixed preamble'.format(path, len(data)))
    _, header_len, ncols, nrows = _V1_COUNTS.unpack_from(data, len(MAGIC))
    body_start = pre + header_len
    expected = body_start + nrows * ncols * 8 + 4
    if len(data) < expected:
        raise LogFormatError('{}: truncated: {} bytes, expected {} ({} rows of {} columns)'.format(
            path, len(data), expected, nrows, ncols))
    if len(data) > expected:
        raise LogFormatError('{}: {} unexpected bytes after the end of the log'.format(path, len(data) - expected))
    (crc,) = _U32.unpack_from(data, expected - 4)
    actual = _crc(memoryview(data)[len(MAGIC):expected - 4])
    if crc != actual:
        raise LogFormatError('{}: corrupted: CRC32 is {:08x}, expected {:08x}'.format(path, actual, crc))
    header = _parse_json(data[pre:body_start], path, 'header')
    if _ncols(header, path) != ncols:
        raise LogFormatError('{}: header lists {} columns, body has {}'.format(path, _ncols(header, path), ncols))
    rows = np.frombuffer(data, dtype='<f8', count=nrows * ncols, offset=body_start)
    return header, rows.reshape(nrows, ncols).astype(float)
