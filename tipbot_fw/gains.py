"""Load, validate and convert to SI a gains file (docs/architecture.md, schema_version 2).

Everything is checked once at start-up, with messages naming the file and the field, and the
matrices are converted to SI here so nothing downstream ever sees cm. The file's ts_s is the
only definition of the control period.

A file carries two estimators: the paper's robust detector (Section 6; A, B, C, L1, L2, G_w,
K, K_w in the file's state units), selectable for reproducing the paper, and the Kalman filter
(the `kalman` block, always SI; the firmware's default), read by _kalman_block below. Both are
then held to physical bounds (check_physics: the tables SCALAR_BOUNDS, MATRIX_BOUNDS,
STRUCTURE_CHECKS, one line per field or property, the Kalman block's among them).
"""
try:
    # the interpreter's own SHA-256: hashlib would load OpenSSL's libcrypto for it, about 3 MB of
    # the controller's memory for one hash of a small file (docs/benchmarks.md, "Memory")
    from _sha256 import sha256
except ImportError:                 # an interpreter without that module (3.12 renamed it)
    from hashlib import sha256

import numpy as np

from tipbot_fw import fields
from tipbot_fw.cores.kalman_design import fold, law_gain, measurement_matrix, spectral_radius
from tipbot_fw.vocabulary import (ACTUATED_INPUTS, DISTURBANCE_NAMES, GAINS_SCHEMA_VERSION, GYRO_BIAS,
                                  INTEGRATOR_NAMES, MEASUREMENT_NAMES, MEASUREMENT_UNITS, N_INPUTS, N_STATES,
                                  STATE_NAMES, STATE_UNITS, UNUSED_INPUT, integrator_count)

# Allowed units per state index, and the factor s with x_file = s * x_SI.
_LENGTH_UNITS = {'m': 1.0, 'cm': 100.0}
_SPEED_UNITS = {'m/s': 1.0, 'cm/s': 100.0}
_STATE_UNITS = ([_LENGTH_UNITS] * 2 + [{'rad': 1.0}] * 3
                + [_SPEED_UNITS] * 2 + [{'rad/s': 1.0}] * 3)

_MATRICES = (('A', N_STATES, N_STATES), ('B', N_STATES, N_INPUTS), ('C', N_STATES, N_STATES),
             ('E', N_STATES, N_INPUTS), ('K', N_INPUTS, N_STATES), ('K_w', N_INPUTS, N_INPUTS),
             ('L1', N_STATES, N_STATES), ('L2', N_STATES, N_STATES),
             ('G_w', N_INPUTS, N_STATES), ('Q', N_STATES, N_STATES), ('R', N_INPUTS, N_INPUTS))

REQUIRED_KEYS = ('schema_version', 'model_variant', 'ts_s', 'state_names', 'state_units',
                 'input_names', 'input_units', 'actuated_inputs', 'A', 'B', 'C', 'E', 'K', 'K_w',
                 'L1', 'L2', 'G_w', 'detector_eigenvalues', 'closed_loop_spectral_radius', 'Q',
                 'R', 'u_max_v', 'parameters', 'parameters_sha256', 'model_options', 'generator', 'kalman')

# Relative tolerance for "this entry is zero" and for the file's own spectral radius claim:
# the file stores 12 significant digits.
_ZERO_RTOL = 1e-9
_RHO_TOL = 1e-6


class GainsError(ValueError):
    """Invalid gains file; the message names the file and the field."""


class Gains(object):
    """Validated gains, all matrices float64 in SI (see module docstring).

    Attributes: path, sha256, schema_version, model_variant, ts_s, u_max_v, state_names,
    input_names, state_units_file, state_scale (x_file = state_scale * x_SI), actuated_inputs,
    A, B, C, E, K, K_w, L1, L2, G_w, Q, R (SI), closed_loop_spectral_radius,
    detector_spectral_radius, parameters_sha256, generator, kalman (KalmanGains).
    """


def _check_zero(m, key, what, f):
    if np.any(np.abs(m) > _ZERO_RTOL * max(1.0, float(np.max(np.abs(m))))):
        f.fail(key, '{} must be zero (link 1 is unactuated)'.format(what))


def gains_from_dict(doc, source='<gains>', sha256=None, expected_ts_s=None, check_kalman=True):
    """Validate a parsed gains document and return Gains in SI. See load_gains().
    check_kalman=False skips the kalman block (a host tool rebuilding it)."""
    if not isinstance(doc, dict):
        raise GainsError('{}: must be a JSON object'.format(source))
    f = fields.Fields(source, GainsError)
    f.require(doc, REQUIRED_KEYS)
    g = Gains()
    g.path = source
    g.sha256 = sha256

    v = doc['schema_version']
    if isinstance(v, bool) or v != GAINS_SCHEMA_VERSION:
        f.fail('schema_version', 'is {!r}, this firmware reads only {}'.format(v, GAINS_SCHEMA_VERSION))
    g.schema_version = GAINS_SCHEMA_VERSION
    if doc['model_variant'] not in ('paper', 'physical'):
        f.fail('model_variant', "is {!r}, expected 'paper' or 'physical'".format(doc['model_variant']))
    g.model_variant = doc['model_variant']

    g.ts_s = _scalar(f, doc, 'ts_s')
    if expected_ts_s is not None and abs(g.ts_s - expected_ts_s) > 1e-12 * expected_ts_s:
        f.fail('ts_s', 'is {!r} s, expected {!r} s'.format(g.ts_s, expected_ts_s))
    g.u_max_v = _scalar(f, doc, 'u_max_v')

    g.state_names = list(f.check('state_names', doc['state_names'], fields.strings(N_STATES)))
    g.input_names = list(f.check('input_names', doc['input_names'], fields.strings(N_INPUTS)))
    units = list(f.check('state_units', doc['state_units'], fields.strings(N_STATES)))
    scale = []
    for i, unit in enumerate(units):
        allowed = _STATE_UNITS[i]
        if unit not in allowed:
            f.fail('state_units[{}]'.format(i), 'is {!r}, expected one of {}'.format(
                unit, ', '.join(sorted(allowed))))
        scale.append(allowed[unit])
    for i in range(5):      # a position and its rate in one length unit (m with m/s, cm with cm/s)
        if units[i + 5] != units[i] + '/s':
            f.fail('state_units[{}]'.format(i + 5), 'is {!r}, the rate of state {} in {!r} must be in {!r}'.format(
                units[i + 5], g.state_names[i], units[i], units[i] + '/s'))
    g.state_units_file = units
    g.state_scale = np.array(scale)
    input_units = f.check('input_units', doc['input_units'], fields.strings(N_INPUTS))
    for i, unit in enumerate(input_units):
        if unit != 'V':
            f.fail('input_units[{}]'.format(i), "is {!r}, expected 'V'".format(unit))
    if doc['actuated_inputs'] != ACTUATED_INPUTS:
        f.fail('actuated_inputs', 'is {!r}, expected {!r}'.format(doc['actuated_inputs'], ACTUATED_INPUTS))
    g.actuated_inputs = list(ACTUATED_INPUTS)

    file_m = {}
    for key, rows, cols in _MATRICES:
        file_m[key] = np.array(f.check(key, doc[key], fields.matrix(rows, cols)), dtype=float)
    if np.max(np.abs(file_m['C'] - np.eye(N_STATES))) > _ZERO_RTOL:
        f.fail('C', 'must be the identity: the signal chain measures all 10 states')
    _check_zero(file_m['B'][:, UNUSED_INPUT], 'B', 'column 2 (u_th1)', f)
    _check_zero(file_m['K'][UNUSED_INPUT, :], 'K', 'row 2 (u_th1)', f)
    _check_zero(file_m['G_w'][UNUSED_INPUT, :], 'G_w', 'row 2 (w_th1)', f)
    _check_zero(file_m['K_w'][UNUSED_INPUT, :], 'K_w', 'row 2 (u_th1)', f)
    _check_zero(file_m['K_w'][:, UNUSED_INPUT], 'K_w', 'column 2 (w_th1)', f)

    f.check('detector_eigenvalues', doc['detector_eigenvalues'], fields.numbers(N_STATES))
    claimed_rho = f.number('closed_loop_spectral_radius', doc['closed_loop_spectral_radius'])
    for key in ('parameters_sha256', 'generator'):
        f.check(key, doc[key], fields.string)
    for key in ('parameters', 'model_options'):
        f.check(key, doc[key], fields.obj)

    # To SI: x_file = S x_SI, so A_SI = S^-1 A S, B_SI = S^-1 B, K_SI = K S, G_w_SI = G_w S,
    # L_SI = S^-1 L S (L maps a measurement, in state units, to a state). C = I is unchanged.
    s = g.state_scale
    inv = 1.0 / s
    g.A = file_m['A'] * inv[:, None] * s[None, :]
    g.B = file_m['B'] * inv[:, None]
    g.C = np.eye(N_STATES)
    g.E = file_m['E'] * inv[:, None]
    g.K = file_m['K'] * s[None, :]
    g.K_w = file_m['K_w']
    g.L1 = file_m['L1'] * inv[:, None] * s[None, :]
    g.L2 = file_m['L2'] * inv[:, None] * s[None, :]
    g.G_w = file_m['G_w'] * s[None, :]
    g.Q = file_m['Q'] * s[:, None] * s[None, :]
    g.R = file_m['R']

    _check_bounds(g, f, ('A', 'B', 'K'))      # first: a product of a 1e308 entry is no radius
    with np.errstate(all='ignore'):
        rho = spectral_radius(g.A - g.B.dot(g.K))
    if rho >= 1.0:
        f.fail('K', 'does not stabilize A: spectral radius of A - B K is {:.6f} >= 1'.format(rho))
    if abs(rho - claimed_rho) > _RHO_TOL * max(1.0, rho):
        f.fail('closed_loop_spectral_radius', 'is {!r} but A - B K has {!r}'.format(claimed_rho, rho))
    abar = (np.eye(N_STATES) - g.L2.dot(g.C)).dot(g.A)
    rho_det = spectral_radius(abar - g.L1.dot(g.C))
    if rho_det >= 1.0:
        f.fail('L1', 'gives an unstable detector: spectral radius of Abar - L1 C is {:.6f} >= 1'.format(rho_det))
    g.closed_loop_spectral_radius = rho
    g.detector_spectral_radius = rho_det
    g.parameters_sha256 = doc['parameters_sha256']
    g.generator = doc['generator']
    g.parameters = doc['parameters']
    g.model_options = doc['model_options']
    g.kalman = _kalman_block(doc['kalman'], f) if check_kalman else None
    from tipbot_fw.preflight import check_block     # the pre-flight check's figures (issue 24)
    g.preflight = check_block(f, doc.get('preflight'))
    check_physics(g, f)
    return g


# ---------------------------------------------------------------------------- physical bounds
# Table-driven, so that new fields (another estimator's matrices) add a line, not code.
# Scalars: field -> (lo, hi, unit, why), checked before anything uses them.
SCALAR_BOUNDS = {
    'ts_s': (0.001, 0.050, 's', 'a loop period of 1 to 50 ms (the brick cannot tick faster; slower does not balance)'),
    'u_max_v': (1.0, 11.0, 'V', 'a motor voltage limit an EV3 battery can give (tipbot_fw.guard.plausibility)'),
}
# Matrices, in SI after the unit conversion: field -> largest |entry| a design of this robot can
# have, and why. 10 to 100 times what the committed designs have: a relabelled unit (x100) or a
# scaled matrix shows up here, or in a structure check below.
MATRIX_BOUNDS = {
    'A': (100.0, 'a discrete model at 1-50 ms is close to the identity'),
    'B': (10.0, 'one volt for one period moves no state that far'),
    'E': (10.0, 'as B: the disturbances are input disturbances in volts'),
    'K': (1e4, 'V per SI unit: more saturates the motors on one sensor count'),
    'K_w': (5.0, 'V per V of estimated disturbance: more than compensating it'),
    'L1': (100.0, 'the detector gains of a stable detector'),
    'L2': (100.0, 'the detector gains of a stable detector'),
    'G_w': (1e5, 'V per SI unit of innovation'),
    # the Kalman block (SI), where the file has one (a host tool rebuilding it reads without)
    'kalman.A': (100.0, 'as A: the augmented model adds constant states'),
    'kalman.B': (10.0, 'as B'),
    'kalman.L': (1e3, 'state change per unit of innovation in one period (the committed filters: below 70)'),
    'kalman.K': (1e4, 'as K'),
    'kalman.law.M': (1e5, 'the folded law: K and the filter times the wheel radius or 1/R_w (committed: below 500)'),
    'kalman.law.state_bounds': (1e5, 'the fixed-point range of a state (m, rad, m/s, rad/s, V; the integrators\' '
                                'm s: 2^15): larger leaves no resolution'),
}
# Structure checks: (field, function(g) -> problem or None). The Section 6 detector's disturbance
# estimate inverts the input disturbance's effect (w^ = G_w C E w), and its L2 is E G_w.
_STRUCTURE_RTOL = 1e-6


def _disturbance_inverse(g):
    err = np.max(np.abs(g.G_w.dot(g.C).dot(g.E)[np.ix_(ACTUATED_INPUTS, ACTUATED_INPUTS)] - np.eye(len(ACTUATED_INPUTS))))
    if err > _STRUCTURE_RTOL:
        return ('does not recover an input disturbance: G_w C E differs from the identity on the actuated inputs '
                'by up to {:.3g} (a scaled G_w?)'.format(err))
    return None


def _detector_l2(g):
    err = np.max(np.abs(g.L2 - g.E.dot(g.G_w)))
    if err > _STRUCTURE_RTOL * max(1.0, float(np.max(np.abs(g.L2)))):
        return 'is not E G_w (they differ by up to {:.3g}): L2 and G_w come from different designs'.format(err)
    return None


def _kalman_check(check):
    """A structure check of the Kalman block: none for a file read without it."""
    return lambda g: None if g.kalman is None else check(g, g.kalman)


def _kalman_measures(g, k):
    if np.max(np.abs(k.C - measurement_matrix(k.n, k.wheel_radius_m, k.n - k.n_filter))) > \
            _ZERO_RTOL * max(1.0, 1.0 / k.wheel_radius_m):
        return ('must measure [d/R_w - th1 (2), th2, th3, th1_dot + gyro_bias] with R_w = '
                'kalman.wheel_radius_m')
    return None


def _kalman_robot(g, k):
    act = ACTUATED_INPUTS
    if np.max(np.abs(k.A[:10, :10] - g.A)) > 1e-9 * max(1.0, float(np.max(np.abs(g.A)))) or \
            np.max(np.abs(k.B[:10] - g.B[:, act])) > 1e-9 * max(1.0, float(np.max(np.abs(g.B)))):
        return 'has a robot block that differs from the file\'s A, B (in SI)'
    return None


def _kalman_law(g, k):
    """K_a = [K_act, K_w_act on the estimated disturbances, 0 on the bias, the integrators']: the
    file's own law (its integrators' gains are the block's own)."""
    law = law_gain(g.K, g.K_w, k.disturbance_inputs, k.K[:, k.n_filter:])
    err = np.abs(k.K - law)
    if np.max(err) > 1e-9 * max(1.0, float(np.max(np.abs(law)))):
        j = int(np.unravel_index(np.argmax(err), err.shape)[1])
        return 'is not the file\'s law: its column {} ({}) differs from the file\'s {} (in SI)'.format(
            j, k.state_names[j], 'K' if j < 10 else ('K_w' if j < k.n_filter - 1 else 'zero of the gyro bias'))
    return None


def _kalman_stable(g, k):
    nf = k.n_filter     # the integrators are no estimate: their own "error" does not decay
    with np.errstate(all='ignore'):     # an overflow is an inf, which the check refuses
        rho = spectral_radius((np.eye(nf) - k.L[:nf].dot(k.C[:, :nf])).dot(k.A[:nf, :nf]))
    if rho >= 1.0:
        return 'gives an unstable filter: spectral radius of (I - L C) A is {:.6f} >= 1'.format(rho)
    return None


def _kalman_wheel(g, k):
    rw = g.parameters.get('rw_m')
    if fields.is_number(rw) and rw > 0 and abs(k.wheel_radius_m - rw) > _ZERO_RTOL * rw:
        return 'is {!r} m, but the recorded parameters have rw_m = {!r} m'.format(k.wheel_radius_m, rw)
    return None


def _kalman_fold(g, k):
    ref = fold(k.A, k.B, k.C, k.L, k.K, k.wheel_radius_m, k.n - k.n_filter)
    err = np.abs(k.law_M - ref) / np.maximum(1e-300, np.abs(ref).max(axis=1, keepdims=True))
    if np.max(err) > _LAW_RTOL:
        i, j = np.unravel_index(np.argmax(err), err.shape)
        return 'is not the fold of kalman.A, B, C, L, K: entry [{}][{}] is {!r}, the fold gives {!r}'.format(
            i, j, float(k.law_M[i, j]), float(ref[i, j]))
    return None


# The Section 6 detector's (above), then the Kalman filter's: what it measures, the same robot
# and law as the file's own (so the design's closed loop is the stable A - B K checked above),
# a stable filter, and the firmware's folded law made of exactly these matrices.
def _kalman_integral(g, k):
    """The integrators integrate the wheel positions' estimate: z+ = z + ts d^ (A, B, L rows of z
    ts times those of d, C blind to z), nothing else reads them but the law."""
    nf = k.n_filter
    if nf == k.n:
        return None
    ts = g.ts_s
    want_a = ts * k.A[0:2]
    want_a[:, nf:] = np.eye(2)
    parts = ((k.A[nf:], want_a), (k.B[nf:], ts * k.B[0:2]), (k.L[nf:], ts * k.L[0:2]),
             (k.A[:nf, nf:], 0.0), (k.C[:, nf:], 0.0))
    for have, want in parts:
        if np.max(np.abs(have - want)) > 1e-9 * max(1.0, float(np.max(np.abs(want)))):
            return 'has integrators z_r, z_l that are not z + ts d^ at ts_s = {!r} s'.format(ts)
    return None


STRUCTURE_CHECKS = [('G_w', _disturbance_inverse), ('L2', _detector_l2),
                    ('kalman.wheel_radius_m', _kalman_check(_kalman_wheel)), ('kalman.C', _kalman_check(_kalman_measures)), ('kalman.A', _kalman_check(_kalman_robot)),
                    ('kalman.K', _kalman_check(_kalman_law)), ('kalman.L', _kalman_check(_kalman_stable)),
                    ('kalman.integral', _kalman_check(_kalman_integral)),
                    ('kalman.law.M', _kalman_check(_kalman_fold))]

# The wheels in the model and in the recorded parameters: a wheel's back-EMF (and viscous
# friction) acts on its own speed as its input does, scaled: in continuous time the column of
# d_dot in A is -k times the wheel's input column of B, k = (Ke + beta Ra / Km) / R_w (beta only
# with model_options.include_viscous_friction); in discrete time (A - I)[:, d_dot] - ts e_d =
# -k B[:, u], exactly. In SI this holds only if the file's units are the ones its matrices were
# made in: a state relabelled m -> cm moves k a hundredfold.
_WHEELS = ((0, 5, 0, 'right_wheel'), (1, 6, 1, 'left_wheel'))
_WHEEL_RTOL = 1e-3


def _wheel_units(g):
    p = g.parameters
    names = ['rw_m'] + ['{}_{}'.format(r, n) for *_, r in _WHEELS for n in ('ke_v_s', 'beta_nm_s', 'ra_ohm', 'km_nm_a')]
    if not all(fields.is_number(p.get(n)) and p[n] >= 0 for n in names) or not p['rw_m'] > 0:
        return None     # no parameters recorded (a synthetic design): nothing to compare with
    friction = g.model_options.get('include_viscous_friction', True) is not False
    for pos, rate, inp, role in _WHEELS:
        a = (g.A - np.eye(N_STATES))[:, rate].copy()
        a[pos] -= g.ts_s
        b = g.B[:, inp]
        if not b.dot(b) > 0:
            return 'has no effect of the {} input'.format(role)
        k_fit = -a.dot(b) / b.dot(b)
        km = p[role + '_km_nm_a']
        k_par = (p[role + '_ke_v_s'] + (p[role + '_beta_nm_s'] * p[role + '_ra_ohm'] / km if friction and km > 0 else 0.0)) / p['rw_m']
        if not abs(k_fit - k_par) <= _WHEEL_RTOL * abs(k_par):
            return ('disagree with the matrices: in SI the {} back-EMF is {:.4g} V s/m by the matrices and {:.4g} by the '
                    'recorded parameters (a unit relabelled without converting the matrices?)'.format(role, k_fit, k_par))
    return None


def _scalar(f, doc, key):
    lo, hi, unit, why = SCALAR_BOUNDS[key]
    v = f.number(key, doc[key])
    if not lo <= v <= hi:
        f.fail(key, 'is {!r} {}, expected {} to {} {}: {}'.format(v, unit, lo, hi, unit, why))
    return v


def check_physics(g, f):
    """The bounds and structure checks above on validated Gains g (SI); f: the file's Fields."""
    problem = _wheel_units(g)
    if problem:
        f.fail('state_units', problem)
    _check_bounds(g, f, sorted(MATRIX_BOUNDS))
    for key, check in STRUCTURE_CHECKS:
        problem = check(g)
        if problem:
            f.fail(key, problem)


def _check_bounds(g, f, keys):
    """MATRIX_BOUNDS of these keys (before any product of them: an entry of 1e308 overflows)."""
    for key in keys:
        bound, why = MATRIX_BOUNDS[key]
        value = _matrix(g, key)
        if value is None:
            continue
        largest = float(np.max(np.abs(value)))
        if not largest <= bound:
            f.fail(key, 'has an entry of {:.4g} (in SI), beyond {:g}: {}'.format(largest, bound, why))


def _matrix(g, key):
    """The SI matrix a MATRIX_BOUNDS key names (None: a Kalman field of a file read without it)."""
    if key.startswith('kalman.'):
        if g.kalman is None:
            return None
        return getattr(g.kalman, _KALMAN_ATTRIBUTES.get(key[len('kalman.'):], key[len('kalman.'):]))
    return getattr(g, key)


def load_gains(path, expected_ts_s=None):
    """Read, hash, validate and convert the gains file at `path`; GainsError on any problem.

    expected_ts_s: if given, the file's ts_s must equal it.
    """
    return load_gains_document(path, expected_ts_s)[1]


def load_gains_document(path, expected_ts_s=None):
    """-> (the file's document as read, its Gains): load_gains for a tool that also derives
    another document from the file's (the host's baselines); the document has passed every check."""
    doc, data = fields.read_json(path, GainsError)
    return doc, gains_from_dict(doc, path, sha256(data).hexdigest(), expected_ts_s)


# ---------------------------------------------------------------------------------------------
# The Kalman block (schema 2): the firmware's default estimator (tipbot_fw.cores.kalman), SI units.
KALMAN_KEYS = ('state_names', 'state_units', 'measurement_names', 'measurement_units', 'wheel_radius_m',
               'A', 'B', 'C', 'L', 'K', 'law', 'noise')
# its states: x (STATE_NAMES), the disturbances of some of DISTURBANCE_NAMES, GYRO_BIAS, and
# optionally the law's integrators of the wheel positions (INTEGRATOR_NAMES; tipbot_fw.cores.kalman,
# "Integral action"), the last states of a Kalman block that has them
# The folded law must equal the fold of the block's matrices to this fraction of its row's
# largest entry (the file has 12 significant digits; the fold sums a few dozen products).
_LAW_RTOL = 1e-8
# MATRIX_BOUNDS' names of the block's fields -> KalmanGains attributes
_KALMAN_ATTRIBUTES = {'law.M': 'law_M', 'law.state_bounds': 'state_bounds'}


class KalmanGains(object):
    """The validated `kalman` block: n, state_names, state_units, wheel_radius_m, A (n x n),
    B (n x 4), C (5 x n), L (n x 5), K (4 x n), law_M ((4 + n) x (4 + n + 7)), state_bounds;
    n_filter (the filter's states; the law's integrators z_r, z_l after them, if any) and
    integral_limit_m_s (their authority, None without)."""


def _kalman_block(doc, f):
    """The `kalman` block's fields (names, units, shapes); its structure is in STRUCTURE_CHECKS."""
    f.check('kalman', doc, fields.obj)
    f.require(doc, KALMAN_KEYS, 'kalman.')
    k = KalmanGains()
    names = doc['state_names']
    n = len(names) if isinstance(names, list) else 0
    k.state_names = list(f.check('kalman.state_names', names, fields.strings(n)))
    nz = integrator_count(names) if isinstance(names, list) else 0
    nf = n - nz
    w = names[10:nf - 1]
    if not (11 <= nf <= 15 and tuple(names[:10]) == STATE_NAMES and names[nf - 1] == GYRO_BIAS
            and all(v in DISTURBANCE_NAMES for v in w) and len(set(w)) == len(w)):
        f.fail('kalman.state_names', 'must be the 10 states, some of {}, gyro_bias and optionally {}, got {!r}'.format(
            ', '.join(DISTURBANCE_NAMES), ', '.join(INTEGRATOR_NAMES), names))
    units = list(STATE_UNITS) + ['V'] * len(w) + ['rad/s'] + ['m s'] * nz
    if doc['state_units'] != units:
        f.fail('kalman.state_units', 'must be {!r} (SI), got {!r}'.format(units, doc['state_units']))
    k.state_units = units
    k.disturbance_inputs = [DISTURBANCE_NAMES.index(v) for v in w]
    k.n = n
    k.n_filter = nf
    if doc['measurement_names'] != list(MEASUREMENT_NAMES) or doc['measurement_units'] != list(MEASUREMENT_UNITS):
        f.fail('kalman.measurement_names', 'must be {} (units {})'.format(
            list(MEASUREMENT_NAMES), list(MEASUREMENT_UNITS)))
    k.wheel_radius_m = f.number('kalman.wheel_radius_m', doc['wheel_radius_m'], lo=0.005, hi=0.1, lo_open=False)
    shapes = (('A', n, n), ('B', n, 4), ('C', 5, n), ('L', n, 5), ('K', 4, n))
    for key, rows, cols in shapes:
        setattr(k, key, np.array(f.check('kalman.' + key, doc[key], fields.matrix(rows, cols)), dtype=float))
    f.check('kalman.noise', doc['noise'], fields.obj)
    law = f.check('kalman.law', doc['law'], fields.obj)
    f.require(law, ('M', 'state_bounds'), 'kalman.law.')
    k.law_M = np.array(f.check('kalman.law.M', law['M'], fields.matrix(4 + n, 4 + n + 7)), dtype=float)
    k.state_bounds = f.check('kalman.law.state_bounds', law['state_bounds'], fields.numbers(n))
    if min(k.state_bounds) <= 0:
        f.fail('kalman.law.state_bounds', 'must be positive, got {!r}'.format(k.state_bounds))
    k.reference = _reference_block(doc['reference'], f) if 'reference' in doc else None
    k.integral_limit_m_s = None
    if nz:
        f.require(doc, ('integral',), 'kalman.')
        block = f.check('kalman.integral', doc['integral'], fields.obj)
        f.require(block, ('limit_m_s',), 'kalman.integral.')
        k.integral_limit_m_s = f.number('kalman.integral.limit_m_s', block['limit_m_s'], lo=0.0,
                                        hi=min(k.state_bounds[nf:]) / 2.0)
    return k


# The drive reference (hostsim.model.reference; optional: gains made before it cannot drive).
REFERENCE_COLUMNS = ('v_r', 'v_l', 'a_r', 'a_l')
REFERENCE_G_BOUND = 1e4
# limit name -> its bounds: beyond any two-wheeled EV3 robot (Large motors: 0.6 m/s at most)
REFERENCE_LIMITS = (('speed_mps', 2.0), ('accel_mps2', 10.0), ('jerk_mps3', 100.0), ('yaw_rate_dps', 1000.0),
                    ('yaw_accel_dps2', 1e4), ('yaw_jerk_dps3', 1e5))


class ReferenceGains(object):
    """The validated `kalman.reference` block: G (4 x 4, V per m/s and m/s^2 of v_r, v_l, a_r,
    a_l: the law's term K_a x_ref + u_ff), track_m and the command limits (a dict of floats)."""


def _reference_block(doc, f):
    f.check('kalman.reference', doc, fields.obj)
    f.require(doc, ('columns', 'G', 'track_m', 'limits'), 'kalman.reference.')
    if doc['columns'] != list(REFERENCE_COLUMNS):
        f.fail('kalman.reference.columns', 'must be {!r}, got {!r}'.format(list(REFERENCE_COLUMNS), doc['columns']))
    r = ReferenceGains()
    r.G = np.array(f.check('kalman.reference.G', doc['G'], fields.matrix(4, 4)), dtype=float)
    if not np.abs(r.G).max() <= REFERENCE_G_BOUND:
        f.fail('kalman.reference.G', 'has an entry beyond +-{:g} V per m/s (committed: below 50)'.format(
            REFERENCE_G_BOUND))
    r.track_m = f.number('kalman.reference.track_m', doc['track_m'], lo=0.02, hi=1.0)
    lim = f.check('kalman.reference.limits', doc['limits'], fields.obj)
    r.limits = {}
    for name, hi in REFERENCE_LIMITS:
        f.require(lim, (name,), 'kalman.reference.limits.')
        r.limits[name] = f.number('kalman.reference.limits.' + name, lim[name], lo=0.0, hi=hi)
    return r
