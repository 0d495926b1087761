"""Load, validate and convert to SI a gains file (docs/architecture.md, schema_version 1).

Everything is checked once at start-up, with messages naming the file and the field, and the
matrices are converted to SI here so nothing downstream ever sees cm. The file's ts_s is the
only definition of the control period.
"""
import hashlib
import json
import math

import numpy as np

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


def _fail(source, field, problem):
    raise GainsError('{}: field {} {}'.format(source, field, problem))


def _is_number(v):
    return not isinstance(v, bool) and isinstance(v, (int, float))


def _finite_number(doc, key, source):
    v = doc[key]
    if not _is_number(v) or not math.isfinite(v):
        _fail(source, key, 'must be a finite number, got {!r}'.format(v))
    return float(v)


def _matrix(doc, key, rows, cols, source):
    m = doc[key]
    if not isinstance(m, list) or not all(isinstance(r, list) for r in m):
        _fail(source, key, 'must be a list of rows (a {}x{} matrix)'.format(rows, cols))
    widths = set(len(r) for r in m)
    if len(widths) > 1:
        _fail(source, key, 'has rows of different lengths {}'.format(sorted(widths)))
    shape = (len(m), widths.pop() if widths else 0)
    if shape != (rows, cols):
        _fail(source, key, 'has shape {}x{}, expected {}x{}'.format(shape[0], shape[1], rows, cols))
    for i, row in enumerate(m):
        for j, v in enumerate(row):
            if not _is_number(v):
                _fail(source, key, 'entry [{}][{}] is {!r}, not a number'.format(i, j, v))
            if not math.isfinite(v):
                _fail(source, key, 'entry [{}][{}] is {!r}, not finite'.format(i, j, v))
    return np.array(m, dtype=float)


def _string_list(doc, key, n, source):
    v = doc[key]
    if not isinstance(v, list) or len(v) != n or not all(isinstance(s, str) for s in v):
        _fail(source, key, 'must be a list of {} strings, got {!r}'.format(n, v))
    return list(v)


def _check_zero(m, key, what, source):
    if np.any(np.abs(m) > _ZERO_RTOL * max(1.0, float(np.max(np.abs(m))))):
        _fail(source, key, '{} must be zero (link 1 is unactuated)'.format(what))


def spectral_radius(m):
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def gains_from_dict(doc, source='<gains>', sha256=None, expected_ts_s=None):
    """Validate a parsed gains document and return Gains in SI. See load_gains()."""
    if not isinstance(doc, dict):
        raise GainsError('{}: must be a JSON object'.format(source))
    for key in REQUIRED_KEYS:
        if key not in doc:
            _fail(source, key, 'is missing')
    g = Gains()
    g.path = source
    g.sha256 = sha256

    v = doc['schema_version']
    if isinstance(v, bool) or v != SCHEMA_VERSION:
        _fail(source, 'schema_version', 'is {!r}, this firmware reads only {}'.format(v, SCHEMA_VERSION))
    g.schema_version = SCHEMA_VERSION
    if doc['model_variant'] not in ('paper', 'physical'):
        _fail(source, 'model_variant', "is {!r}, expected 'paper' or 'physical'".format(doc['model_variant']))
    g.model_variant = doc['model_variant']

    g.ts_s = _finite_number(doc, 'ts_s', source)
    if not 0.0 < g.ts_s <= 1.0:
        _fail(source, 'ts_s', 'is {!r} s, expected a period in (0, 1] s'.format(g.ts_s))
    if expected_ts_s is not None and abs(g.ts_s - expected_ts_s) > 1e-12 * expected_ts_s:
        _fail(source, 'ts_s', 'is {!r} s, expected {!r} s'.format(g.ts_s, expected_ts_s))
    g.u_max_v = _finite_number(doc, 'u_max_v', source)
    if not 0.0 < g.u_max_v <= 12.0:
        _fail(source, 'u_max_v', 'is {!r} V, expected a saturation in (0, 12] V'.format(g.u_max_v))

    g.state_names = _string_list(doc, 'state_names', N_STATES, source)
    g.input_names = _string_list(doc, 'input_names', N_INPUTS, source)
    units = _string_list(doc, 'state_units', N_STATES, source)
    scale = []
    for i, unit in enumerate(units):
        allowed = _STATE_UNITS[i]
        if unit not in allowed:
            _fail(source, 'state_units[{}]'.format(i), 'is {!r}, expected one of {}'.format(
                unit, ', '.join(sorted(allowed))))
        scale.append(allowed[unit])
    g.state_units_file = units
    g.state_scale = np.array(scale)
    input_units = _string_list(doc, 'input_units', N_INPUTS, source)
    for i, unit in enumerate(input_units):
        if unit != 'V':
            _fail(source, 'input_units[{}]'.format(i), "is {!r}, expected 'V'".format(unit))
    if doc['actuated_inputs'] != ACTUATED_INPUTS:
        _fail(source, 'actuated_inputs', 'is {!r}, expected {!r}'.format(doc['actuated_inputs'], ACTUATED_INPUTS))
    g.actuated_inputs = list(ACTUATED_INPUTS)

    file_m = {}
    for key, rows, cols in _MATRICES:
        file_m[key] = _matrix(doc, key, rows, cols, source)
    if np.max(np.abs(file_m['C'] - np.eye(N_STATES))) > _ZERO_RTOL:
        _fail(source, 'C', 'must be the identity: the signal chain measures all 10 states')
    _check_zero(file_m['B'][:, UNUSED_INPUT], 'B', 'column 2 (u_th1)', source)
    _check_zero(file_m['K'][UNUSED_INPUT, :], 'K', 'row 2 (u_th1)', source)
    _check_zero(file_m['G_w'][UNUSED_INPUT, :], 'G_w', 'row 2 (w_th1)', source)
    _check_zero(file_m['K_w'][UNUSED_INPUT, :], 'K_w', 'row 2 (u_th1)', source)
    _check_zero(file_m['K_w'][:, UNUSED_INPUT], 'K_w', 'column 2 (w_th1)', source)

    eig = doc['detector_eigenvalues']
    if (not isinstance(eig, list) or len(eig) != N_STATES
            or not all(_is_number(e) and math.isfinite(e) for e in eig)):
        _fail(source, 'detector_eigenvalues', 'must be a list of {} finite numbers'.format(N_STATES))
    claimed_rho = _finite_number(doc, 'closed_loop_spectral_radius', source)
    if not isinstance(doc['parameters_sha256'], str):
        _fail(source, 'parameters_sha256', 'must be a string')
    for key in ('parameters', 'model_options'):
        if not isinstance(doc[key], dict):
            _fail(source, key, 'must be an object')
    if not isinstance(doc['generator'], str):
        _fail(source, 'generator', 'must be a string')

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
        _fail(source, 'K', 'does not stabilize A: spectral radius of A - B K is {:.6f} >= 1'.format(rho))
    if abs(rho - claimed_rho) > _RHO_TOL * max(1.0, rho):
        _fail(source, 'closed_loop_spectral_radius', 'is {!r} but A - B K has {!r}'.format(claimed_rho, rho))
    abar = (np.eye(N_STATES) - g.L2.dot(g.C)).dot(g.A)
    rho_det = spectral_radius(abar - g.L1.dot(g.C))
    if rho_det >= 1.0:
        _fail(source, 'L1', 'gives an unstable detector: spectral radius of Abar - L1 C is {:.6f} >= 1'.format(rho_det))
    g.closed_loop_spectral_radius = rho
    g.detector_spectral_radius = rho_det
    g.parameters_sha256 = doc['parameters_sha256']
    g.generator = doc['generator']
    return g


def load_gains(path, expected_ts_s=None):
    """Read, hash, validate and convert the gains file at `path`; GainsError on any problem.

    expected_ts_s: if given, the file's ts_s must equal it.
    """
    try:
        with open(path, 'rb') as f:
            data = f.read()
    except OSError as e:
        raise GainsError('{}: cannot read: {}'.format(path, e))
    try:
        doc = json.loads(data.decode('utf-8'))
    except (ValueError, UnicodeError) as e:
        raise GainsError('{}: not valid JSON: {}'.format(path, e))
    return gains_from_dict(doc, path, hashlib.sha256(data).hexdigest(), expected_ts_s)
