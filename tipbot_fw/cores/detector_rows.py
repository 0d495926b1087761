"""The detector core's log row (tipbot_fw.cores.detector_core; docs/log-format.md): its layout in
memory, which the core fills with one struct pack and two byte copies, and the file's columns
made of it when the log is read.

In memory: the tick's two clock readings (the loop packs them), the raw readings, the battery,
the bias, the flags, the duties (the device's: polarity applied), the measured state y, the
estimate x~, the disturbance estimate w^ and dcmd, the commands before saturation in duty units
(the always-zero th1 inputs are left out). In the file (to_file): time_s and tick_s from the
clock readings, the volts u = polarity * duty * battery_v / 100 and u_cmd from dcmd.
"""
import numpy as np

from tipbot_fw.vocabulary import ACTUATED, INPUTS, MOTOR_ROLES, STATE_NAMES, STATE_UNITS

_MOTORS = ('r', 'l', '2', '3')      # the duties' and encoders' suffixes, in MOTOR_ROLES order


def _columns():
    return ([('time_s', 's'), ('tick_s', 's')] + [('enc_' + m, 'count') for m in _MOTORS]
            + [('gyro_angle', 'deg'), ('gyro_rate', 'deg/s'), ('battery_v', 'V'), ('gyro_bias', 'deg/s')]
            + [('y_' + n, u) for n, u in zip(STATE_NAMES, STATE_UNITS)]
            + [('xt_' + n, u) for n, u in zip(STATE_NAMES, STATE_UNITS)]
            + [('w_' + n, 'V') for n in INPUTS] + [('u_' + n, 'V') for n in INPUTS]
            + [('u_cmd_' + n, 'V') for n in INPUTS]
            + [('duty_' + m, '%') for m in _MOTORS] + [('flags', 'bits')])


def _mem_names():
    return (['t_start', 't_written'] + ['enc_' + m for m in _MOTORS]
            + ['gyro_angle', 'gyro_rate', 'battery_v', 'gyro_bias', 'flags'] + ['duty_' + m for m in _MOTORS]
            + ['y_' + n for n in STATE_NAMES] + ['xt_' + n for n in STATE_NAMES]
            + ['w_' + n for n in ACTUATED] + ['dcmd_' + n for n in ACTUATED])


class DetectorRows(object):
    """The detector core's row: mem_names in memory, columns in the file (to_file)."""
    estimator = 'detector'
    columns = _columns()
    column_names = [c[0] for c in columns]
    mem_names = _mem_names()
    row_bytes = 8 * len(mem_names)
    flags_index = mem_names.index('flags')

    def __init__(self, polarity):
        self.polarity = tuple(polarity)

    @classmethod
    def col(cls, name):
        """The file column of a name."""
        return cls.column_names.index(name)

    @classmethod
    def mem(cls, name):
        """The memory row's slot (float64) of a name."""
        return cls.mem_names.index(name)

    @classmethod
    def at(cls, name):
        """The byte offset of a name's slot in a memory row."""
        return 8 * cls.mem_names.index(name)

    def header(self):
        """What a reader needs to know of this layout, for the log's header."""
        return {'estimator': self.estimator}

    @classmethod
    def from_header(cls, header):
        return cls([header['config']['polarity'][r] for r in MOTOR_ROLES])

    def to_file(self, mem_rows, t0=0.0):
        """In-memory rows (n x len(mem_names)) -> file rows (n x len(columns)); t0: the clock at
        the start of the first tick."""
        mem_rows = np.asarray(mem_rows, dtype=float)
        out = np.zeros((len(mem_rows), len(self.columns)))
        for f, m in _COPIED:
            out[:, f] = mem_rows[:, m]
        out[:, self.col('time_s')] = mem_rows[:, self.mem('t_start')] - t0
        out[:, self.col('tick_s')] = mem_rows[:, self.mem('t_written')] - mem_rows[:, self.mem('t_start')]
        volts_per_duty = mem_rows[:, self.mem('battery_v')] / 100.0
        for f, m, k in _DERIVED:
            out[:, f] = self.polarity[k] * mem_rows[:, m] * volts_per_duty
        return out


# the file's columns copied from the memory row, and those derived from a duty: (file column,
# memory slot, motor)
_COPIED = [(i, DetectorRows.mem(n)) for i, n in enumerate(DetectorRows.column_names) if n in DetectorRows.mem_names]
_DERIVED = ([(DetectorRows.col('u_' + n), DetectorRows.mem('duty_' + m), k) for k, (n, m) in enumerate(zip(ACTUATED, _MOTORS))]
            + [(DetectorRows.col('u_cmd_' + n), DetectorRows.mem('dcmd_' + n), k) for k, n in enumerate(ACTUATED)])
