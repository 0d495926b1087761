"""Live telemetry: `python3 -m tipbot_fw run --telemetry HOST:PORT` sends one UDP datagram every
few ticks, in the loop's slack after the tick's writes (a side task, tipbot_fw.slack).

Datagram, version 1, little-endian (docs/telemetry.md), HEADER then ROW_FIELDS as float64:

    magic b'TBTM', u16 version, u16 polarity bits (bit i: motor i's polarity is -1, motors
    r, l, th2, th3), u32 seq (datagrams so far), u32 tick, u32 overruns (so far),
    u32 send errors (so far), f64 t0 (the loop's clock at the first tick), then the tick's
    t_start, t_written, battery_v, gyro_bias, flags, duty_r..duty_3, y_d_r..y_th3, w_r..w_th3.

The values are the tick's row of the log as the loop stored it in memory (tipbot_fw.logfile
MEM_NAMES): one struct unpack picks them out of the row's bytes and one pack puts them in the
datagram (row_copier), so a datagram costs two C calls, the counters and one send. ROW_FIELDS is the one mapping from the row to
the datagram: a change of the row's columns needs it (and only it) adapted; a name the row no
longer has is refused when the sender is attached, before the run. decode() gives what the log
gives for the same tick (the file layout's names: time_s, tick_s, u_r, ...).

Sending never blocks and never raises: a datagram that cannot go (nobody listening, no route,
a full buffer) is counted and the loop goes on. Python 3.5, standard library only: the host's
`python -m hostsim watch` decodes with the same module.
"""
import operator
import socket
import struct

from tipbot_fw import logfile

MAGIC = b'TBTM'
VERSION = 1
# HEADER: magic, version, polarity bits, then what changes from datagram to datagram (seq,
# tick, overruns, send errors, t0), packed with the row's values in one call
_VARYING = 'IIIId'
_VARYING_AT = 8
HEADER = struct.Struct('<4sHH' + _VARYING)
ROW_FIELDS = ('t_start', 't_written', 'battery_v', 'gyro_bias', 'flags',
              'duty_r', 'duty_l', 'duty_2', 'duty_3', 'y_d_r', 'y_d_l', 'y_th1', 'y_th2', 'y_th3',
              'w_r', 'w_l', 'w_th2', 'w_th3')
BODY = struct.Struct('<{}d'.format(len(ROW_FIELDS)))
SIZE = HEADER.size + BODY.size
_ROW_BYTES = logfile.MEM_ROW_BYTES
# Default decimation: a datagram every 20 ticks, 10 per second at 5 ms. A datagram costs about
# 10,000 ARMv5 instructions, about 500 a tick at this rate: today's tick (105,400, over its
# 100,000) has room for no more (docs/telemetry.md).
DEFAULT_EVERY = 20
# Decoded inputs: u = polarity * duty * battery_v / 100 (tipbot_fw.logfile.to_file_layout)
_INPUTS = (('u_r', 'duty_r'), ('u_l', 'duty_l'), ('u_th2', 'duty_2'), ('u_th3', 'duty_3'))


class TelemetryError(ValueError):
    """A bad --telemetry target or a datagram that is not a tipbot telemetry datagram."""


def row_copier(names, row_names=logfile.MEM_NAMES, head=''):
    """-> (unpack, pack): unpack(row bytes, byte offset) picks the row's columns `names` (8
    bytes each) as byte strings, pack(datagram, offset, *head values, *those) puts the values of
    the struct format `head` and then those, in the order of `names`. Columns next to each other in both travel as one string, so today's row takes three
    (two C calls and no float objects: on the brick's soft-float ARM, 18 floats unpacked and
    packed again cost three times as much)."""
    missing = [n for n in names if n not in row_names]
    if missing:
        raise TelemetryError('telemetry: the log row has no column {} (tipbot_fw.telemetry.ROW_FIELDS)'
                             .format(', '.join(missing)))
    runs = []       # [first row column, columns]
    for i in (row_names.index(n) for n in names):
        if runs and runs[-1][0] + runs[-1][1] == i:
            runs[-1][1] += 1
        else:
            runs.append([i, 1])
    in_row = sorted(range(len(runs)), key=lambda r: runs[r][0])
    fmt, at = '<', 0
    for r in in_row:
        start, n = runs[r]
        fmt += ('{}x'.format(8 * (start - at)) if start > at else '') + '{}s'.format(8 * n)
        at = start + n
    unpack = struct.Struct(fmt).unpack_from
    pack = struct.Struct('<' + head + ''.join('{}s'.format(8 * n) for _, n in runs)).pack_into
    if in_row != list(range(len(runs))):
        order = operator.itemgetter(*[in_row.index(r) for r in range(len(runs))])
        return (lambda data, offset: order(unpack(data, offset))), pack
    return unpack, pack


def parse_target(text):
    """'HOST:PORT' (IPv6: '[::1]:PORT') -> (host, port); TelemetryError naming the problem."""
    host, sep, port = text.rpartition(':')
    host = host[1:-1] if host.startswith('[') and host.endswith(']') else host
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise TelemetryError('--telemetry must be HOST:PORT (a port 1-65535), got {!r}'.format(text))
    return host, int(port)


def polarity_bits(polarity):
    return sum(1 << i for i, p in enumerate(polarity) if p < 0)


class TelemetrySender(object):
    """UDP datagrams to `target` (HOST:PORT) every `every` ticks. The address is resolved
    here, before any device is touched (TelemetryError if it cannot be)."""

    def __init__(self, target, every=DEFAULT_EVERY):
        host, port = parse_target(target)
        try:
            family, kind, proto, _, address = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM)[0]
            self.sock = socket.socket(family, kind, proto)
        except (OSError, UnicodeError) as e:
            raise TelemetryError('--telemetry {}: {}'.format(target, e))
        self.sock.setblocking(False)
        try:
            self.sock.connect(address)      # connected: send() skips the address lookup each time
        except OSError as e:
            self.sock.close()
            raise TelemetryError('--telemetry {}: {}'.format(target, e))
        self.target = target
        self.every = max(1, int(every))
        self.count = [0, 0]     # datagrams sent, not sent
        self.first_error = None

    def attach(self, log, stats, polarity):
        """The side task sending tick k - 1's row of `log` (a tipbot_fw.logfile.LogBuffer that
        the loop fills; stats: its LoopStats) when called with k. A closure over locals: on the
        brick each attribute lookup of a method would cost as much as a C call here."""
        pick, put = row_copier(ROW_FIELDS, head=_VARYING)
        out = bytearray(SIZE)
        HEADER.pack_into(out, 0, MAGIC, VERSION, polarity_bits(polarity), 0, 0, 0, 0, 0.0)
        send, data, capacity, every = self.sock.send, log.data, log.capacity, self.every
        count = self.count = [0, 0]     # sent, not sent

        def send_tick(k):
            sent, errors = count
            # the loop has set log.t0 before the first tick
            put(out, _VARYING_AT, sent + errors, k - 1, stats.overruns, errors, log.t0,
                *pick(data, ((k - 1) % capacity) * _ROW_BYTES))
            try:
                send(out)
                count[0] = sent + 1
            except OSError as e:     # nobody listening, no route, buffer full: counted, never raised
                count[1] = errors + 1
                if self.first_error is None:
                    self.first_error = str(e)
            return k + every
        return send_tick

    @property
    def sent(self):
        return self.count[0]

    @property
    def errors(self):
        return self.count[1]

    def summary(self):
        """For the log header and the owner."""
        return {'target': self.target, 'every_ticks': self.every, 'sent': self.sent, 'errors': self.errors,
                'first_error': self.first_error}

    def close(self):
        self.sock.close()


def decode(data):
    """A datagram -> dict: seq, tick, overruns, send_errors, and the tick's values under the
    log's column names (time_s, tick_s, battery_v, gyro_bias, flags, duty_*, y_*, w_*, u_*).
    TelemetryError if it is not a version-1 tipbot telemetry datagram."""
    if len(data) != SIZE or data[:4] != MAGIC:
        raise TelemetryError('not a tipbot telemetry datagram ({} bytes)'.format(len(data)))
    magic, version, pol, seq, tick, overruns, errors, t0 = HEADER.unpack_from(data, 0)
    if version != VERSION:
        raise TelemetryError('telemetry version {} (this reader: {})'.format(version, VERSION))
    v = dict(zip(ROW_FIELDS, BODY.unpack_from(data, HEADER.size)))
    t_start, t_written = v.pop('t_start'), v.pop('t_written')
    # the same arithmetic as the log's file layout, so that the values are the log's to the bit
    out = {'seq': seq, 'tick': tick, 'overruns': overruns, 'send_errors': errors,
           'time_s': t_start - t0, 'tick_s': t_written - t_start}
    out.update(v)
    volts_per_duty = v['battery_v'] / 100.0
    for i, (u, duty) in enumerate(_INPUTS):
        out[u] = (-1.0 if pol >> i & 1 else 1.0) * v[duty] * volts_per_duty
    return out
