"""The paper's core (config estimator: detector): signal chain, Section 6 detector, LQR.

Selectable for reproducing the paper; the firmware's default is tipbot_fw.cores.kalman. Raw readings
+ battery voltage -> duties and a log row, no I/O, no time (tipbot_fw.cores.core describes the
interface both cores share). Pipeline per tick: signal chain -> detector + control law (one
matrix product) -> saturation -> duty -> log row.

On the brick each Python float handled one by one costs about as much as a multiply-add inside
the product, so the core moves data by struct packing and byte copies between preallocated
buffers, and folds every constant factor into the matrix (tipbot_fw.cores.detector):
  v_bytes (the product's input v): [x~_k | w-_k-1 | duty_k | y_k | y_k+1 (used entries)], float64
  z_bytes (its output z):          [x~_k+1 | w-_k | dcmd_k+1], 18 float64
duty_k are the duties written to the motors at tick k and dcmd_k+1 the next ones before
rounding and saturation: the matrix's u columns carry polarity * battery_v / 100 (duty -> the
applied u in volts) and its u rows polarity * 100 / battery_v (volts -> duty), rescaled only when
the battery voltage changes (about once a second). Multiplying by +-1 is exact, so the polarity
changes no result; x~ and w- are in SI units and volts as in docs/architecture.md.
After the product z_bytes goes over the start of v_bytes (x~_k+1 and w-_k land in place; the dcmd
bytes land on the duty slot, which is packed next, with y_k+1 after it).
"""
import operator
import struct

import numpy as np

from tipbot_fw.config import motor_polarity
from tipbot_fw.cores.core import Core
from tipbot_fw.cores.detector import N_FIXED, N_OUT, U_OUT, V_U, V_W, V_Y0, W_OUT, X_OUT, fold
from tipbot_fw.cores.detector_rows import DetectorRows
from tipbot_fw.cores.saturation import battery_constants, to_duties
from tipbot_fw.cores.signal_chain import SignalChain, lowpass_coefficient
from tipbot_fw.vocabulary import ACTUATED_INPUTS, FLAG_BITS, N_STATES, STOP_FLAGS

FALL = FLAG_BITS['fall']
JOINT_LIMIT = FLAG_BITS['joint_limit']

_DCMD = struct.Struct('<4d')
_DUTY_Y = struct.Struct('<14d')
_SCALARS = struct.Struct('<{}d'.format(DetectorRows.mem('duty_r') - DetectorRows.mem('enc_r')))  # enc_r..flags
# byte offsets in v_bytes / z_bytes / a memory row
_V_U = 8 * V_U.start
_V_Y1 = 8 * N_FIXED
_Z_U = 8 * U_OUT.start
_Z_END = 8 * N_OUT
_ROW_SCALARS = DetectorRows.at('enc_r')
_ROW_DUTY_Y = DetectorRows.at('duty_r')
_ROW_Z = DetectorRows.at('xt_d_r')
_ROW_END = DetectorRows.row_bytes
_MEM_Y = DetectorRows.mem('y_d_r')
assert (X_OUT, W_OUT) == (slice(0, 10), V_W) and (U_OUT.stop, V_U.stop, V_Y0.stop) == (18, 18, N_FIXED)
assert ((_ROW_Z - _ROW_DUTY_Y) // 8, (_ROW_END - _ROW_Z) // 8) == (4 + N_STATES, N_OUT)


def _picker(indices):
    """y -> tuple of y[i] for i in indices, in C when there are at least two."""
    if len(indices) >= 2:
        return operator.itemgetter(*indices)
    return lambda y: tuple(y[i] for i in indices)


class DetectorCore(Core):
    """Per-tick computation; its whole state is recorded in each log row.

    set_gyro_bias(bias_dps) after the calibration, set_battery(battery_v) before the first tick and whenever the voltage changes (outside the
    ticks: it rescales the matrix); start(enc, gyro, buf, offset) for the first tick,
    step(enc, gyro, buf, offset) for every later one. Both write the tick's memory row
    (DetectorRows.mem_names), except its time columns, into the bytearray buf at byte offset
    `offset`, and return (duties, stop): duties for Devices.write_duties, stop nonzero
    (FALL / JOINT_LIMIT bits) if the motors must be stopped now instead.
    """

    estimator = 'detector'
    max_count_step = None       # float64 arithmetic: no fixed-point range to keep

    @staticmethod
    def row_layout(gains, config):
        """The log row of this core (before the core is made: the log's header)."""
        return DetectorRows(motor_polarity(config))

    def __init__(self, gains, config, counts_per_rot=(360, 360, 360, 360), layout=None):
        self.chain = None
        self.chain_args = (config, gains.ts_s)
        self.counts_per_rot = tuple(counts_per_rot)
        cutoff = config['filters']['disturbance_cutoff_hz']
        self.w_lowpass = 1.0 if cutoff is None else lowpass_coefficient(cutoff, gains.ts_s)
        M, self.y1_used = fold(gains, self.w_lowpass)
        self.polarity = motor_polarity(config)
        self.pol = np.array(self.polarity, dtype=float)
        self.M_volts = M    # as folded: inputs and outputs in volts
        self.M = M.copy()   # rescaled in place by set_battery(): self.dot stays bound to it
        self.dot = self.M.dot
        self.pick_y1 = _picker(self.y1_used)
        self.pack_y1 = struct.Struct('<{}d'.format(len(self.y1_used))).pack_into
        self.v_bytes = bytearray(8 * M.shape[1])
        self.v = np.frombuffer(self.v_bytes, dtype='<f8')
        self.z_bytes = bytearray(_Z_END)
        self.z = np.frombuffer(self.z_bytes, dtype='<f8')
        # what the log row copies from v: duty_k+1 and y_k+1 (a view: no temporary copy)
        self.v_duty_y = memoryview(self.v_bytes)[_V_U:_V_Y1]
        self.K_act = gains.K[ACTUATED_INPUTS, :]
        self.u_max_v = gains.u_max_v
        lim = config['limits']
        self.limits = (lim['th1_rad'], lim['th2_rad'], lim['th3_rad'])
        # as (-limit, limit) pairs: negating on every tick costs
        self.bounds = (-lim['th1_rad'], lim['th1_rad'], -lim['th2_rad'], lim['th2_rad'],
                       -lim['th3_rad'], lim['th3_rad'])
        self.battery_v = None
        self.x0 = None      # x~_0, for the log header
        self.rows = layout or self.row_layout(gains, config)

    def set_gyro_bias(self, gyro_bias_dps):
        """The calibrated bias (deg/s): the signal chain starts from it."""
        self.chain = SignalChain(self.chain_args[0], self.chain_args[1], gyro_bias_dps, self.counts_per_rot)

    def header(self):
        """What the log header needs to replay this core (docs/log-format.md)."""
        doc = self.rows.header()
        doc.update({'encoder_offsets': list(self.chain.offsets) if self.chain and self.chain.offsets else None,
                    'x_tilde_0': self.x0})
        return doc

    def angles(self, mem_row):
        """(th1, th2, th3) of a memory row, for the stop message."""
        y = mem_row[_MEM_Y:_MEM_Y + 5]
        return float(y[2]), float(y[3]), float(y[4])

    def set_battery(self, battery_v):
        """Fold this battery voltage (and the polarities) into the matrix; see module docstring."""
        scale, volts_per_duty, self.dlim = battery_constants(self.u_max_v, battery_v)
        self.battery_v = battery_v
        self.duty_scale = scale
        M = self.M
        M[:] = self.M_volts
        M[:, V_U] *= self.pol * volts_per_duty
        M[U_OUT, :] *= (self.pol * scale)[:, None]

    # x~_k, w-_k, duty_k (as written) and y_k after a tick, for inspection and tests
    @property
    def xt(self):
        return self.v[0:N_STATES].tolist()

    @property
    def w(self):
        return self.v[V_W].tolist()

    @property
    def duties(self):
        return [int(d) for d in self.v[V_U]]

    @property
    def y(self):
        return self.v[V_Y0].tolist()

    def start(self, enc, gyro, buf, offset):
        """First tick: x~_0 = y_0 (all states are measured, C = I), w^ = 0, u_0 = sat(-K x~_0)."""
        y = self.chain.start(enc, gyro)
        self.x0 = list(y)
        dcmd = -self.K_act.dot(np.array(y)) * (self.pol * self.duty_scale)
        self.z[:] = np.concatenate([y, np.zeros(4), dcmd])
        return self._finish(enc, gyro, y, buf, offset)

    def step(self, enc, gyro, buf, offset):
        """Every later tick: the equations of tipbot_fw.cores.detector as z = M v, one numpy call."""
        y = self.chain.update(enc, gyro)
        self.pack_y1(self.v_bytes, _V_Y1, *self.pick_y1(y))
        self.dot(self.v, self.z)
        return self._finish(enc, gyro, y, buf, offset)

    def _finish(self, enc, gyro, y, buf, offset):
        vb = self.v_bytes
        zb = self.z_bytes
        d0, d1, d2, d3, flags = to_duties(_DCMD.unpack_from(zb, _Z_U), self.dlim)
        lo1, hi1, lo2, hi2, lo3, hi3 = self.bounds
        if not lo1 <= y[2] <= hi1:
            flags |= FALL
        if not (lo2 <= y[3] <= hi2 and lo3 <= y[4] <= hi3):
            flags |= JOINT_LIMIT
        # next tick's v: x~_k+1 and w-_k in place, then duty_k+1 and y_k+1 after them
        vb[0:_Z_END] = zb
        _DUTY_Y.pack_into(vb, _V_U, d0, d1, d2, d3, *y)
        _SCALARS.pack_into(buf, offset + _ROW_SCALARS, *enc, *gyro, self.battery_v,
                           self.chain.bias_used_dps, flags)
        buf[offset + _ROW_DUTY_Y:offset + _ROW_Z] = self.v_duty_y
        buf[offset + _ROW_Z:offset + _ROW_END] = zb
        return [d0, d1, d2, d3], flags & STOP_FLAGS

    def skip(self, periods):
        """Periods the loop missed: the paper's core, kept as published, resumes from its last
        estimate (the Kalman core predicts through them: tipbot_fw.cores.kalman)."""

    def wind_down(self):
        """The paper's law has no integrators (tipbot_fw.cores.kalman's may have): nothing to keep."""
        return False

    def restore(self, row, encoder_offsets):
        """State as right after the tick that produced the (file layout) log row `row`."""
        r = [float(x) for x in row]
        col = DetectorRows.col
        y0, xt, w, duty = col('y_d_r'), col('xt_d_r'), col('w_r'), col('duty_r')
        y = r[y0:y0 + N_STATES]
        self.chain.restore(encoder_offsets, y, r[col('gyro_bias')], r[col('gyro_rate')])
        self.v[0:N_STATES] = r[xt:xt + N_STATES]
        self.v[V_W] = [r[w + i] for i in ACTUATED_INPUTS]
        _DUTY_Y.pack_into(self.v_bytes, _V_U, *(r[duty:duty + 4] + y))
