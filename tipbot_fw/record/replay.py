"""Replay a log through the same core the robot ran: the raw readings and battery voltages of
the log go in, the rows that come out must equal the logged ones (time columns excepted).

The Kalman core (the default) computes in integers: its replay is bit-exact on any machine
(its integer matrix is built from the gains file's decimals by elementwise IEEE-754 operations
in a fixed order, tipbot_fw.cores.fixedpoint). The detector core computes in float64: bit-exact on
the machine that wrote the log, within the last bits across machines (docs/log-format.md).

signals() turns the rows of either core into the estimates and inputs in SI, for plots,
metrics, the export and the simulator (host tools); the telemetry decoder
(tipbot_fw.record.telemetry.decode) computes the same values, with the same arithmetic, from a
datagram.
"""
import numpy as np

from tipbot_fw import vocabulary
from tipbot_fw.config import motor_polarity
from tipbot_fw.cores import kalman_rows
from tipbot_fw.cores.core import make_core, row_layout
from tipbot_fw.cores.kalman import wheel_m_per_count
from tipbot_fw.record import logfile
from tipbot_fw.vocabulary import ACTUATED_INPUTS


def core_from_header(header, gains, check_gains=True):
    """A core configured exactly as the logged run.

    check_gains: refuse gains other than the logged ones (False: replay the readings through
    other gains, to see what they would have commanded).
    """
    if check_gains and header['gains']['sha256'] != gains.sha256:
        raise ValueError('gains {} (sha256 {}) are not the ones of the log (sha256 {})'.format(
            gains.path, gains.sha256, header['gains']['sha256']))
    core = make_core(gains, header['config'], header['counts_per_rot'])
    core.set_gyro_bias(header['calibration']['gyro_bias_dps'])
    return core


def replay(header, rows, gains, check_gains=True):
    """-> recomputed rows (same shape as rows; time columns copied from the log).

    Each run of consecutive ticks the log holds (logfile.segments: a long run's head and its
    kept tail) is replayed on its own: from tick 0 (start) if it is the run's start, else
    re-seeded from its first row, which holds the core's whole state (core.restore; that row is
    copied, not recomputed), and every later row recomputed from there.
    """
    core = core_from_header(header, gains, check_gains)
    layout = core.rows
    logged = _logged_layout(header, layout)
    one = logfile.LogBuffer(1, layout)
    loop_bits = vocabulary.FLAG_BITS['overrun'] | (vocabulary.SKIP_MAX << vocabulary.SKIP_SHIFT) | vocabulary.WOUND_DOWN
    skip_bits = vocabulary.SKIP_MAX << vocabulary.SKIP_SHIFT
    flags = layout.col('flags')
    readings = _reader(logged)
    starts = dict(logfile.segment_rows(header, len(rows)))
    # the drive reference the run followed, from its log (a log of a firmware before it has none:
    # its columns end before the reference's)
    driven = getattr(layout, 'has_reference', False) and 'reference' in header
    if logged is layout:
        out = np.array(rows, dtype=float)
    else:
        # a what-if with gains of other states (the integrators): their rows, the log's times
        if len(starts) > 1 or set(starts.values()) != {0}:
            raise ValueError('a ring-buffer log replays only through gains of the same states as its own')
        out = np.zeros((len(rows), len(layout.columns)))
        out[:, 0:2] = np.asarray(rows, dtype=float)[:, 0:2]
    width = out.shape[1]
    for i in range(len(rows)):
        enc, gyro, battery_v = readings(rows[i])
        if battery_v != core.battery_v:
            core.set_battery(battery_v)
        if driven:
            core.set_reference(logged.reference_ints(rows[i]))
        loops = int(rows[i, flags]) & loop_bits
        if i not in starts:
            core.step(enc, gyro, one.data, 0)
        elif starts[i] == 0:
            core.start(enc, gyro, one.data, 0)
        else:
            core.restore(rows[i], header['encoder_offsets'])
            _between_ticks(core, loops, skip_bits)
            continue
        out[i, 2:] = layout.to_file(one.mem)[0, 2:width]
        # the overrun flag and the periods skipped after the tick are the loop's, not the core's;
        # the core predicted through those periods before the next tick, as on the robot
        out[i, flags] = int(out[i, flags]) | loops
        _between_ticks(core, loops, skip_bits)
    return out


def _between_ticks(core, loops, skip_bits):
    """What the loop did to the core after a tick, as its flags say: the periods it skipped
    (predicted through), then the integrators kept within their limit (tipbot_fw.loop)."""
    core.skip((loops & skip_bits) >> vocabulary.SKIP_SHIFT)
    if loops & vocabulary.WOUND_DOWN:
        core.wind_down()


def _logged_layout(header, layout):
    """The layout of the log's own rows: `layout` (the replaying core's) when the log has the
    same columns, else the one its header describes."""
    names = [c['name'] for c in header['columns']]
    if names[:len(layout.column_names)] == list(layout.column_names):
        return layout
    return logfile.layout_from_header(header)


def what_if_header(header, gains):
    """The header of rows that replay() made with other gains (their core's columns)."""
    layout = row_layout(gains, header['config'])
    return dict(header, columns=logfile.columns_header(layout.columns), state_names=layout.header().get(
        'state_names', header.get('state_names')))


def _reader(layout):
    """row -> (the raw readings as the device gave them (ints), the battery voltage)."""
    e = [layout.col(c) for c in ('enc_r', 'enc_l', 'enc_2', 'enc_3')]
    g = [layout.col(c) for c in ('gyro_angle', 'gyro_rate')]
    b = layout.col('battery_v')

    def read(r):
        r = r.tolist()
        return (tuple(int(r[i]) for i in e), (int(r[g[0]]), int(r[g[1]])), r[b])
    return read


class Signals(object):
    """The estimates and inputs of a log's rows, SI (signals()): x_hat (n x 10), w_hat (n x 5,
    V), u (the applied inputs, n x 5, V), u_cmd (the law's output before rounding and
    saturation, n x 5, V), gyro_bias (n, rad/s: the Kalman core's; None for the detector's),
    reference (n x 6, kalman_rows.REFERENCE_COLUMNS: a driven run's; else None)."""
    __slots__ = ('x_hat', 'w_hat', 'u', 'u_cmd', 'gyro_bias', 'reference')

    def __init__(self, x_hat, w_hat, u, u_cmd, gyro_bias=None, reference=None):
        self.x_hat, self.w_hat, self.u, self.u_cmd = x_hat, w_hat, u, u_cmd
        self.gyro_bias, self.reference = gyro_bias, reference


def signals(header, rows, gains):
    """The estimates and inputs of a log's rows, for either core -> Signals."""
    names = [c['name'] for c in header['columns']]
    col = names.index
    pol = motor_polarity(header['config'])
    n = len(rows)
    u = np.zeros((n, 5))
    volts_per_duty = rows[:, col('battery_v')] / 100.0      # as the detector's file columns
    for k, name in enumerate(('duty_r', 'duty_l', 'duty_2', 'duty_3')):
        u[:, ACTUATED_INPUTS[k]] = pol[k] * rows[:, col(name)] * volts_per_duty
    if header.get('estimator', 'detector') == 'detector':
        block = lambda first, width: rows[:, col(first):col(first) + width]
        return Signals(block('xt_d_r', 10), block('w_r', 5), u, block('u_cmd_r', 5))
    kal = gains.kalman
    xi = np.column_stack([rows[:, col('xi_' + s)] for s in kal.state_names])
    x = xi.copy()
    cpr = header['counts_per_rot']
    zeros = header.get('encoder_offsets') or [0, 0, 0, 0]
    for i, name in ((0, 'enc_r'), (1, 'enc_l')):
        x[:, i] += wheel_m_per_count(kal.wheel_radius_m, pol[i], cpr[i]) * (rows[:, col(name)] - zeros[i])
    w_hat = np.zeros((n, 5))
    for j, i in enumerate(kal.disturbance_inputs):
        w_hat[:, ACTUATED_INPUTS[i]] = x[:, 10 + j]
    u_cmd = np.zeros((n, 5))
    u_cmd[:, ACTUATED_INPUTS] = -x.dot(kal.K.T)
    out = Signals(x[:, :10], w_hat, u, u_cmd, x[:, kal.n_filter - 1])
    if 'ref_d_r' in names:
        # driving: u = -K_a (x^ - x_ref) + u_ff = -K_a x^ + K_a's wheel columns d_ref + G r
        # (tipbot_fw.cores.kalman, "Driving"); the reference as the log has it
        ref = np.column_stack([rows[:, col(c)] for c, _ in kalman_rows.REFERENCE_COLUMNS])
        extra = ref[:, 0:2].dot(kal.K[:, 0:2].T)
        if kal.reference is not None:
            extra += ref[:, 2:].dot(kal.reference.G.T)
        u_cmd[:, ACTUATED_INPUTS] += extra
        out.reference = ref
    return out
