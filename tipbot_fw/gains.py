"""Load, validate and convert to SI a gains file (docs/architecture.md, schema_version 1).

Everything is checked once at start-up, with messages naming the file and the field, and the
matrices are converted to SI here so nothing downstream ever sees cm. The file's ts_s is the
only definition of the control period.
"""
import hashlib

import numpy as np

from tipbot_fw import fields

SCHEMA_VERSION = 1
N_STATES = 10
N_INPUTS = 5
ACTUATED_INPUTS = [0, 1, 3, 4]
UNUSED_INPUT = 2  # u_th1: link 1 has no motor

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
                 'R', 'u_max_v', 'parameters', 'parameters_sha256', 'model_options', 'generator')

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
    detector_spectral_radius, parameters_sha256, generator.
    """


def _check_zero(m, key, what, f):
    if np.any(np.abs(m) > _ZERO_RTOL * max(1.0, float(np.max(np.abs(m))))):
        f.fail(key, '{} must be zero (link 1 is unactuated)'.format(what))


def spectral_radius(m):
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def gains_from_dict(doc, source='<gains>', sha256=None, expected_ts_s=None):
    """Validate a parsed gains document and return Gains in SI. See load_gains()."""
    if not isinstance(doc, dict):
        raise GainsError('{}: must be a JSON object'.format(source))
    f = fields.Fields(source, GainsError)
    f.require(doc, REQUIRED_KEYS)
    g = Gains()
    g.path = source
    g.sha256 = sha256

    v = doc['schema_version']
    if isinstance(v, bool) or v != SCHEMA_VERSION:
        f.fail('schema_version', 'is {!r}, this firmware reads only {}'.format(v, SCHEMA_VERSION))
    g.schema_version = SCHEMA_VERSION
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
    check_physics(g, f)
    return g


# ---------------------------------------------------------------------------- physical bounds
# Table-driven, so that new fields (another estimator's matrices) add a line, not code.
# Scalars: field -> (lo, hi, unit, why), checked before anything uses them.
SCALAR_BOUNDS = {
    'ts_s': (0.001, 0.050, 's', 'a loop period of 1 to 50 ms (the brick cannot tick faster; slower does not balance)'),
    'u_max_v': (1.0, 11.0, 'V', 'a motor voltage limit an EV3 battery can give (tipbot_fw.plausibility)'),
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


STRUCTURE_CHECKS = [('G_w', _disturbance_inverse), ('L2', _detector_l2)]

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
    for key, check in STRUCTURE_CHECKS:
        problem = check(g)
        if problem:
            f.fail(key, problem)
    for key, (bound, why) in sorted(MATRIX_BOUNDS.items()):
        largest = float(np.max(np.abs(getattr(g, key))))
        if not largest <= bound:
            f.fail(key, 'has an entry of {:.4g} (in SI), beyond {:g}: {}'.format(largest, bound, why))


def load_gains(path, expected_ts_s=None):
    """Read, hash, validate and convert the gains file at `path`; GainsError on any problem.

    expected_ts_s: if given, the file's ts_s must equal it.
    """
    doc, data = fields.read_json(path, GainsError)
    return gains_from_dict(doc, path, hashlib.sha256(data).hexdigest(), expected_ts_s)
