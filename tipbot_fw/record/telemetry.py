"""Live telemetry: `python3 -m tipbot_fw run --telemetry HOST:PORT` sends one UDP datagram every
few ticks, in the loop's slack after the tick's writes (a side task, tipbot_fw.side_tasks).

Datagram, version 2, little-endian (docs/telemetry.md): HEADER, then the tick's values (BODY),
then, for the Kalman core, the constants that make them SI:

    magic b'TBTM', u16 version, u8 layout (0: the detector core's row; KALMAN | the bits of
    the filter's disturbance states: the Kalman core's; | REFERENCE: a driven run's, the drive
    reference's six integers after the wheel counts, their resolutions last; | INTEGRAL: the
    law's integrators z_r, z_l after the gyro bias), u8 polarity bits
    (bit i: motor i's polarity is -1, motors r, l, th2, th3), u32 seq (datagrams so far),
    u32 tick, u32 overruns (so far), u32 send errors (so far), f64 t0 (the loop's clock at the
    first tick), then ROW_FIELDS[core] of the tick's row, 8 bytes each, as the row holds them
    (the detector's floats; the Kalman core's duties, carried state xi and wheel counts as
    int64), then for the Kalman core the states' resolutions (f64 each) and the wheels' metres
    per count (2 x f64).

The values are the tick's row of the log as the loop stored it in memory (tipbot_fw.record.logfile's
row layouts): one struct unpack picks them out of the row's bytes and one pack puts them in
the datagram (row_copier), so a datagram costs two C calls, the counters and one send, and the
brick converts nothing (the constants are packed once, when the sender is attached). ROW_FIELDS
is the one mapping from each core's row to the datagram: a change of a row's columns needs it
(and only it) adapted; a name the row no longer has is refused when the sender is attached,
before the run. decode() makes of either the same SI values that the replay's signals() gives
for the log's tick (tipbot_fw.record.replay), with the same arithmetic, bit for bit: DECODED.

Sending never blocks and never raises: a datagram that cannot go (nobody listening, no route,
a full buffer) is counted and the loop goes on. Python 3.5, standard library only: the host's
`python -m hostsim watch` decodes with the same module.
"""
import operator
import struct

from tipbot_fw.vocabulary import INTEGRATOR_NAMES, STATE_NAMES, integrator_count
from tipbot_fw.cores.kalman_rows import REFERENCE_COLUMNS

MAGIC = b'TBTM'
VERSION = 2
# HEADER: magic, version, layout, polarity bits, then what changes from datagram to datagram
# (seq, tick, overruns, send errors, t0), packed with the row's values in one call
_VARYING = 'IIIId'
_VARYING_AT = 8
HEADER = struct.Struct('<4sHBB' + _VARYING)
KALMAN = 0x80
# A driven run's datagrams (the Kalman core with a course) carry the drive reference too: its six
# integers after the wheel counts, their SI resolutions after the constants
REFERENCE = 0x40
REFERENCE_NAMES = tuple(name for name, _ in REFERENCE_COLUMNS)
DISTURBANCES = ('w_r', 'w_l', 'w_th2', 'w_th3')
# A law with integral action (tipbot_fw.cores.kalman): its integrators' states after the gyro bias
INTEGRAL = 0x20
# The row's columns each datagram carries, per core; 'xi_*' stands for the Kalman filter's
# states in the row's order (10 robot states, its disturbance states, the gyro bias)
ROW_FIELDS = {
    'detector': ('t_start', 't_written', 'battery_v', 'flags', 'duty_r', 'duty_l', 'duty_2', 'duty_3')
                + tuple('xt_' + s for s in STATE_NAMES) + tuple(DISTURBANCES),
    'kalman': ('t_start', 't_written', 'battery_v', 'flags', 'duty_r', 'duty_l', 'duty_2', 'duty_3',
               'xi_*', 'rel_r', 'rel_l'),
}
# What decode() gives besides the counters (seq, tick, overruns, send_errors), for either core:
# the log's time columns, the battery, the flags, the duties, the state estimate (xt_*: the
# detector's x~, the Kalman filter's x^), the disturbance estimate (0 for an input the filter
# does not estimate) and the applied inputs, under the names `hostsim export` gives them.
DECODED = (['time_s', 'tick_s', 'battery_v', 'flags', 'duty_r', 'duty_l', 'duty_2', 'duty_3']
           + ['xt_' + s for s in STATE_NAMES] + list(DISTURBANCES) + ['u_r', 'u_l', 'u_th2', 'u_th3'])
# and for a driven run's datagrams (REFERENCE) the reference, as the log's ref_* columns
DECODED_DRIVING = DECODED + list(REFERENCE_NAMES)
# Default decimation: a datagram every 20 ticks, 10 per second at 5 ms (docs/telemetry.md).
DEFAULT_EVERY = 20
_DUTIES = ('duty_r', 'duty_l', 'duty_2', 'duty_3')
_INPUTS = ('u_r', 'u_l', 'u_th2', 'u_th3')


class TelemetryError(ValueError):
    """A bad --telemetry target or a datagram that is not a tipbot telemetry datagram."""


def row_copier(names, row_names, head=''):
    """-> (unpack, pack): unpack(row bytes, byte offset) picks the row's columns `names` (8
    bytes each) as byte strings, pack(datagram, offset, *head values, *those) puts the values of
    the struct format `head` and then those, in the order of `names`. Columns next to each other
    in both travel as one string, so a row takes three or four (two C calls and no number objects:
    on the brick's soft-float ARM, 20 floats unpacked and packed again cost three times as
    much)."""
    missing = [n for n in names if n not in row_names]
    if missing:
        raise TelemetryError('telemetry: the log row has no column {} (tipbot_fw.record.telemetry.ROW_FIELDS)'
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


class Layout(object):
    """A datagram's layout: `code` (the header's layout byte), `fields` (the row's columns it
    carries), `body` (their struct), `consts` (the Kalman core's constants' struct, or None),
    `states` (the Kalman filter's state names), `size`."""

    def __init__(self, code):
        self.code = code
        if code == 0:
            self.fields = ROW_FIELDS['detector']
            self.states = None
            self.body = struct.Struct('<{}d'.format(len(self.fields)))
            self.consts = None
        elif code & KALMAN and not code & ~(KALMAN | REFERENCE | INTEGRAL | 15):
            self.states = (list(STATE_NAMES) + [w for i, w in enumerate(DISTURBANCES) if code >> i & 1] + ['gyro_bias']
                           + (list(INTEGRATOR_NAMES) if code & INTEGRAL else []))
            n = len(self.states)
            self.fields = self.expand(ROW_FIELDS['kalman'], self.states)
            nr = len(REFERENCE_NAMES) if code & REFERENCE else 0
            self.fields += REFERENCE_NAMES[:nr]
            self.body = struct.Struct('<4d4q{}q2q{}q'.format(n, nr))
            self.consts = struct.Struct('<{}d2d{}d'.format(n, nr))
        else:
            raise TelemetryError('telemetry layout {:#x} is not one this reader knows'.format(code))
        self.size = HEADER.size + self.body.size + (self.consts.size if self.consts else 0)

    @staticmethod
    def expand(fields, states):
        out = []
        for name in fields:
            out += ['xi_' + s for s in states] if name == 'xi_*' else [name]
        return tuple(out)

    @classmethod
    def of_rows(cls, rows, driving=False):
        """The layout for a core's row layout (tipbot_fw.record.logfile.DetectorRows / KalmanRows);
        driving: with the drive reference."""
        if rows.estimator == 'detector':
            return cls(0)
        names = list(rows.state_names)
        nz = integrator_count(names)
        w = names[10:len(names) - nz - 1]
        bad = [s for s in w if s not in DISTURBANCES]
        if bad:
            raise TelemetryError('telemetry: the Kalman filter\'s state {} has no place in a datagram'.format(bad[0]))
        return cls(KALMAN | (REFERENCE if driving else 0) | (INTEGRAL if nz else 0)
                   | sum(1 << DISTURBANCES.index(s) for s in w))


class TelemetrySender(object):
    """UDP datagrams to `target` (HOST:PORT) every `every` ticks. The address is resolved
    here, before any device is touched (TelemetryError if it cannot be)."""

    def __init__(self, target, every=DEFAULT_EVERY):
        import socket       # here: a run without telemetry does not keep the socket modules in memory
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
        self.size = None        # bytes a datagram has (attach)

    def attach(self, log, stats, core):
        """The side task sending tick k - 1's row of `log` (a tipbot_fw.record.logfile.LogBuffer that
        the loop fills with `core`'s rows; stats: its LoopStats) when called with k. A closure
        over locals: on the brick each attribute lookup of a method would cost as much as a C
        call here."""
        rows = core.rows
        layout = Layout.of_rows(rows, getattr(core, 'plan', None) is not None)
        pick, put = row_copier(layout.fields, rows.mem_names, head=_VARYING)
        out = bytearray(layout.size)
        HEADER.pack_into(out, 0, MAGIC, VERSION, layout.code, polarity_bits(core.polarity), 0, 0, 0, 0, 0.0)
        if layout.consts is not None:
            ref = list(rows.ref_lsb) if layout.code & REFERENCE else []
            layout.consts.pack_into(out, HEADER.size + layout.body.size,
                                    *(list(rows.state_lsb) + list(core.wheel_m) + ref))
        send, data, capacity, every, row_bytes = self.sock.send, log.data, log.capacity, self.every, log.row_bytes
        count = self.count = [0, 0]     # sent, not sent

        def send_tick(k):
            sent, errors = count
            # the loop has set log.t0 before the first tick
            put(out, _VARYING_AT, sent + errors, k - 1, stats.overruns, errors, log.t0,
                *pick(data, ((k - 1) % capacity) * row_bytes))
            try:
                send(out)
                count[0] = sent + 1
            except OSError as e:     # nobody listening, no route, buffer full: counted, never raised
                count[1] = errors + 1
                if self.first_error is None:
                    self.first_error = str(e)
            return k + every
        self.size = layout.size
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
    """A datagram -> dict: seq, tick, overruns, send_errors, and DECODED, the tick's values as
    the replay's signals() gives them for the log (the same arithmetic: time_s = t_start - t0,
    u = polarity * duty * (battery_v / 100), the Kalman filter's x^ = xi 2^-q plus the wheels'
    metres per count times their counts; a driven run's reference, DECODED_DRIVING, as the log's
    ref_* columns: its integers times their resolutions). TelemetryError if it is not a version-2
    tipbot telemetry datagram."""
    if len(data) < HEADER.size or data[:4] != MAGIC:
        raise TelemetryError('not a tipbot telemetry datagram ({} bytes)'.format(len(data)))
    magic, version, code, pol, seq, tick, overruns, errors, t0 = HEADER.unpack_from(data, 0)
    if version != VERSION:
        raise TelemetryError('telemetry version {} (this reader: {})'.format(version, VERSION))
    layout = Layout(code)
    if len(data) != layout.size:
        raise TelemetryError('not a tipbot telemetry datagram ({} bytes, its layout has {})'.format(
            len(data), layout.size))
    v = dict(zip(layout.fields, layout.body.unpack_from(data, HEADER.size)))
    out = {'seq': seq, 'tick': tick, 'overruns': overruns, 'send_errors': errors,
           'time_s': v['t_start'] - t0, 'tick_s': v['t_written'] - v['t_start'],
           'battery_v': v['battery_v'], 'flags': v['flags']}
    volts_per_duty = v['battery_v'] / 100.0
    for i, (duty, u) in enumerate(zip(_DUTIES, _INPUTS)):
        out[duty] = float(v[duty])
        out[u] = (-1.0 if pol >> i & 1 else 1.0) * out[duty] * volts_per_duty
    if layout.states is None:
        for name in DECODED[8:-4]:
            out[name] = v[name]
        return out
    consts = layout.consts.unpack_from(data, HEADER.size + layout.body.size)
    n = len(layout.states)
    x = dict((s, v['xi_' + s] * consts[j]) for j, s in enumerate(layout.states))
    x['d_r'] += consts[n] * v['rel_r']
    x['d_l'] += consts[n + 1] * v['rel_l']
    for s in STATE_NAMES:
        out['xt_' + s] = x[s]
    for w in DISTURBANCES:
        out[w] = x.get(w, 0.0)
    if code & REFERENCE:
        for i, name in enumerate(REFERENCE_NAMES):
            out[name] = v[name] * consts[n + 2 + i]
    return out
