"""The Kalman core's log row (tipbot_fw.cores.kalman; docs/log-format.md): its layout in memory,
named once, and the file's columns made of it when the log is read.

In memory: the two clock readings (packed by the loop), then HEAD_FLOATS (float64), then int64s:
the duties, the carried state xi (xi_j 2^q_j: q, the state_exponents of
tipbot_fw.cores.fixedpoint), the product's inputs (the wheels' count changes, the four counts
from their zeros, the gyro's raw rate; one copy of the core's integer vector) and, with a
drive reference, the product's constant 1 and the reference's integers (ref_lsb: SI per
integer, set by the core). In the file: the raw counts, the duties, xi and the reference in SI.
Every byte offset the core writes at is derived here from the names (FLOATS_AT, INTS_AT).
"""
import struct

import numpy as np

from tipbot_fw.cores import fixedpoint

# The clock readings, then the floats the core packs in one call, then the integers from here on
TIMES = ('t_start', 't_written')
HEAD_FLOATS = ('battery_v', 'flags', 'gyro_angle')
FLOATS = struct.Struct('<{}d'.format(len(HEAD_FLOATS)))
FLOATS_AT = 8 * len(TIMES)
INTS_AT = FLOATS_AT + FLOATS.size
DUTIES = ('duty_r', 'duty_l', 'duty_2', 'duty_3')
# the product's integer inputs after xi (tipbot_fw.cores.kalman.N_IN of them)
INPUTS = ('dcount_r', 'dcount_l', 'rel_r', 'rel_l', 'rel_2', 'rel_3', 'gyro_rate')
# The drive reference (tipbot_fw.cores.kalman, tipbot_fw.drive.plan): the file's columns after
# the state's; a log of a firmware before it has none.
REFERENCE_COLUMNS = (('ref_d_r', 'm'), ('ref_d_l', 'm'), ('ref_v_r', 'm/s'), ('ref_v_l', 'm/s'),
                     ('ref_a_r', 'm/s^2'), ('ref_a_l', 'm/s^2'))
REFERENCE_NAMES = [name for name, _ in REFERENCE_COLUMNS]
_ENCODERS = ('enc_r', 'enc_l', 'enc_2', 'enc_3')


def kalman_columns(state_names, state_units):
    """(name, unit) of the Kalman core's file columns for the filter's states."""
    return ([('time_s', 's'), ('tick_s', 's')] + [(e, 'count') for e in _ENCODERS]
            + [('gyro_angle', 'deg'), ('gyro_rate', 'deg/s'), ('battery_v', 'V'), ('flags', 'bits')]
            + [(d, '%') for d in DUTIES] + [('xi_' + s, u) for s, u in zip(state_names, state_units)])


class KalmanRows(object):
    """The Kalman core's row for a filter's states (module docstring).

    offsets: the encoder zeros (the first tick's counts), set by the core's first tick or read
    from the log; the file's enc_* columns are the counts from them plus them."""
    estimator = 'kalman'
    flags_index = (FLOATS_AT // 8) + HEAD_FLOATS.index('flags')
    ints_start = INTS_AT // 8
    n_inputs = len(INPUTS)

    def __init__(self, state_names, state_units, state_exponents, offsets=None, has_reference=True,
                 ref_lsb=None):
        self.state_names = list(state_names)
        self.state_units = list(state_units)
        self.n = n = len(self.state_names)
        self.q = [int(e) for e in state_exponents]
        if len(self.q) != n:
            raise ValueError('{} state exponents for {} states'.format(len(self.q), n))
        self.state_lsb = np.array([2.0 ** -e for e in self.q])
        self.mem_names = (list(TIMES) + list(HEAD_FLOATS) + list(DUTIES) + ['xi_' + s for s in self.state_names]
                          + list(INPUTS))
        self.has_reference = has_reference
        self.ref_lsb = ref_lsb
        self.columns = kalman_columns(self.state_names, self.state_units)
        if has_reference:       # after the product's constant input (tipbot_fw.cores.kalman)
            self.mem_names += ['one'] + REFERENCE_NAMES
            self.columns += list(REFERENCE_COLUMNS)
        self.row_bytes = 8 * len(self.mem_names)
        self.column_names = [c[0] for c in self.columns]
        self.offsets = offsets

    @classmethod
    def for_gains(cls, kal):
        """The layout of a gains file's Kalman block (tipbot_fw.gains.KalmanGains)."""
        return cls(kal.state_names, kal.state_units, fixedpoint.state_exponents(kal.state_bounds))

    def int_index(self, name):
        """The index of a name among the row's integers."""
        return self.mem_names.index(name) - self.ints_start

    def header(self):
        """What a reader needs to know of this layout, for the log's header (the encoder zeros
        follow with the first rows)."""
        doc = {'estimator': self.estimator, 'state_names': self.state_names, 'state_units': self.state_units,
               'fixed_point': {'state_exponents': self.q}}
        if self.has_reference:
            doc['reference'] = {'columns': REFERENCE_NAMES, 'lsb': self.ref_lsb}
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
            if not (isinstance(ref, dict) and ref.get('columns') == REFERENCE_NAMES
                    and (lsb is None or (isinstance(lsb, list) and len(lsb) == len(REFERENCE_COLUMNS)
                                         and all(isinstance(v, float) for v in lsb)))):
                raise ValueError('reference must name the columns {} and their lsb (numbers, or null)'.format(
                    REFERENCE_NAMES))
            return cls(names, units, q, offsets, True, lsb)
        return cls(names, units, q, offsets, False)

    def to_file(self, mem_rows, t0=0.0):
        """In-memory rows (a float64 view, k x len(mem_names)) -> file rows (float64)."""
        mem = np.ascontiguousarray(mem_rows, dtype='<f8')
        ints = mem[:, self.ints_start:].view('<i8')
        n = self.n
        col, slot, at = self.col, self.mem_names.index, self.int_index
        out = np.zeros((len(mem), len(self.columns)))
        out[:, col('time_s')] = mem[:, slot('t_start')] - t0
        out[:, col('tick_s')] = mem[:, slot('t_written')] - mem[:, slot('t_start')]
        zeros = self.offsets or (0, 0, 0, 0)
        for j, (enc, rel) in enumerate(zip(_ENCODERS, INPUTS[2:6])):
            out[:, col(enc)] = ints[:, at(rel)] + zeros[j]
        for name in HEAD_FLOATS:
            out[:, col(name)] = mem[:, slot(name)]
        out[:, col('gyro_rate')] = ints[:, at('gyro_rate')]
        d = at(DUTIES[0])
        out[:, col(DUTIES[0]):col(DUTIES[0]) + 4] = ints[:, d:d + 4]
        xi, c = at('xi_' + self.state_names[0]), col('xi_' + self.state_names[0])
        out[:, c:c + n] = ints[:, xi:xi + n] * self.state_lsb[None, :]
        if self.has_reference:
            nr = len(REFERENCE_COLUMNS)
            r, c = at(REFERENCE_NAMES[0]), col(REFERENCE_NAMES[0])
            out[:, c:c + nr] = ints[:, r:r + nr] * np.array(self.ref_lsb or [0.0] * nr)[None, :]
        return out

    def reference_ints(self, file_row):
        """The reference's integers of a file row (the inverse of to_file's SI, exact)."""
        base = self.col('ref_d_r')
        return [int(round(file_row[base + i] / lsb)) if lsb else 0 for i, lsb in enumerate(self.ref_lsb)]

    def col(self, name):
        return self.column_names.index(name)
