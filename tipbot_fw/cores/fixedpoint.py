"""Integer (fixed-point) form of a linear per-tick law: one int64 product and one shift per tick.

Why: the brick's ARM926 has no FPU. In numpy's dot a soft-float multiply-add costs about 120
ARMv5 instructions, an int64 one about 19 (measured on the virtual brick: a 19x25 product is
62,100 instructions in float64, 46,700 in float32, 15,000 in int64). So the Kalman core keeps its
state as integers and runs

    acc = M_int v            (int64; v: integers, see below)
    out = acc >> shifts      (arithmetic shift per row: round half up, the rounding constant
                              2^(shift-1) is folded into the constant column)

Each state x_j is held as z_j = round(x_j 2^q_j) with q_j = STATE_BITS - ceil(log2 X_j), where
X_j bounds |x_j| (a physical bound, from the gains file): its resolution is X_j / 2^32 or finer.
Row i of the product is computed at 2^E_i, with E_i the largest exponent for which no sum can
overflow: sum_j |M_int_ij| V_j <= 2^ACC_BITS, V_j the bound of v_j (2^STATE_BITS for a state,
the declared bound of an input). The shift of a state row is E_i - q_i, of an output row E_i.

Everything here is deterministic across IEEE-754 machines: exponents come from math.frexp, the
integer matrix from elementwise float64 products in a fixed order and floor(x + 0.5), so the
host's replay builds the very integers the brick built and replays a log bit for bit.
"""
import math

import numpy as np

STATE_BITS = 32        # |z_j| <= 2^32 while |x_j| <= X_j
ACC_BITS = 62          # worst-case |acc_i| <= 2^62: one bit of the int64 spare


def ceil_log2(x):
    """Smallest integer e with 2^e >= x (x > 0), exactly (math.frexp, no libm rounding)."""
    m, e = math.frexp(float(x))
    return e - 1 if m == 0.5 else e


def state_exponents(bounds):
    """q_j for state bounds X_j."""
    return [STATE_BITS - ceil_log2(x) for x in bounds]


def row_exponents(m_abs_scaled, v_bounds):
    """E_i so that sum_j |m_abs_scaled_ij| 2^E_i v_bounds_j <= 2^ACC_BITS (with the rounding of
    each entry and the rounding constant accounted for). m_abs_scaled: |M| times the largest
    column and row factors (a list of rows of floats); v_bounds: the bound of each entry of v."""
    rounding = float(sum(v_bounds))     # each entry rounds by <= 1/2: at most this much more
    out = []
    for row in m_abs_scaled:
        s = 0.0
        for a, v in zip(row, v_bounds):
            s += a * v
        e = ACC_BITS - ceil_log2(s * (1.0 + 2.0 ** -20))
        while e > 0 and s * 2.0 ** e + rounding > 2.0 ** ACC_BITS:
            e -= 1
        out.append(e)
    return out


def quantize(m, col_factor, row_factor, row_exp):
    """floor(M_ij * col_factor_j * row_factor_i * 2^E_i + 0.5) as int64, in that order."""
    t = m * np.asarray(col_factor, dtype=float)[None, :]
    t = t * np.asarray(row_factor, dtype=float)[:, None]
    t = t * np.array([2.0 ** e for e in row_exp])[:, None]
    return np.floor(t + 0.5).astype(np.int64)


def round_half_up(x, exp):
    """round(x 2^exp) as a Python int (x a float)."""
    return int(math.floor(x * 2.0 ** exp + 0.5))


def accumulator_bound(m_int, v_bounds):
    """Worst-case |acc| of each row, as floats (for the overflow check)."""
    return np.abs(m_int).astype(float).dot(np.asarray(v_bounds, dtype=float))
