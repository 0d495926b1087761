"""Robot configuration: defaults in default_config.json, overridden field by field by --config.

Every field is validated; errors name the file and the dotted field path. Fields (SI units):

  ports.{right_wheel,left_wheel,joint2,joint3}  motor port, outA..outD, all different
  ports.gyro                                   sensor port, in1..in4
  drivers.<device>                             expected driver name (checked by the device layer)
  stop_action                                  what a stopped motor does: coast or brake
  polarity.<motor>                             +1/-1: multiplies the measured counts AND the duty
  gyro_sign                                    +1/-1: +1 if a positive gyro rate is a forward tilt
  wheel_radius_m                               wheel radius R_w
  start_pose_rad.{th1,th2,th3}                 pose the robot is held in at start (th1 integrates
                                               from it; th2, th3 are the joint encoders' zeros)
  limits.th1_rad, limits.th2_rad, limits.th3_rad   |angle| beyond -> motors stopped in that tick
  limits.min_battery_v                         refuse to start below this battery voltage
  limits.max_consecutive_overruns              this many late ticks in a row -> safe stop
  filters.encoder_rate_cutoff_hz               low-pass of the differentiated encoder positions
  filters.gyro_rate_cutoff_hz                  low-pass of the gyro rate (th1_dot)
  filters.disturbance_cutoff_hz                low-pass of the disturbance estimate w^ before the
                                               control law uses it (tipbot_fw.detector); null = none
  gyro_calibration.settle_s                    gyro samples read and not used at start (the first
                                               ones after the mode switch may be the old mode's)
  gyro_calibration.duration_s                  then the stillness window for the bias
  gyro_calibration.max_rate_spread_dps         max - min rate allowed in that window
  gyro_calibration.max_bias_dps                largest |mean rate| taken for a bias (more: turning)
  gyro_calibration.max_angle_change_deg        angle change allowed in that window beyond the
                                               drift the mean rate explains (tipbot_fw.calibration)
  gyro_bias_time_constant_s                    slow bias tracking while running; null = off (the
                                               default: see tipbot_fw.signals for why)
  gyro_bias_quiet_dps                          the tracking learns only from samples whose
                                               corrected rate is within +- this (the robot at rest)
  battery_period_s                             battery re-read period (outside the ticks)
  log_max_rows                                 log buffer rows (a ring: the newest are kept)
  realtime_priority                            SCHED_FIFO priority to request, 0 = don't
"""
import copy
import json
import math
import os

DEFAULT_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'default_config.json')

MOTORS = ('right_wheel', 'left_wheel', 'joint2', 'joint3')


class ConfigError(ValueError):
    """Invalid configuration; the message names the file and the field."""


def _number(lo=None, hi=None, lo_open=True, integer=False, allow_null=False):
    if integer:
        kind = 'an integer'
    else:
        kind = 'a number'
    if lo is not None and hi is not None:
        kind += ' in {}{}, {}]'.format('(' if lo_open else '[', lo, hi)
    elif lo is not None:
        kind += ' {} {}'.format('>' if lo_open else '>=', lo)
    if allow_null:
        kind += ' or null'

    def check(v):
        if v is None and allow_null:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return 'must be {}, got {!r}'.format(kind, v)
        if integer and not isinstance(v, int):
            return 'must be {}, got {!r}'.format(kind, v)
        if not math.isfinite(v):
            return 'must be {}, got {!r}'.format(kind, v)
        if lo is not None and (v <= lo if lo_open else v < lo):
            return 'must be {}, got {!r}'.format(kind, v)
        if hi is not None and v > hi:
            return 'must be {}, got {!r}'.format(kind, v)
        return None
    return check


def _one_of(*choices):
    def check(v):
        if isinstance(v, bool) or v not in choices:
            return 'must be one of {}, got {!r}'.format(', '.join(repr(c) for c in choices), v)
        return None
    return check


def _nonempty_str(v):
    if not isinstance(v, str) or not v:
        return 'must be a non-empty string, got {!r}'.format(v)
    return None


_SIGN = _one_of(1, -1)
_MOTOR_PORT = _one_of('outA', 'outB', 'outC', 'outD')

# Leaf validators by dotted path; the set of paths is also the set of allowed fields.
SPEC = {
    'ports.right_wheel': _MOTOR_PORT,
    'ports.left_wheel': _MOTOR_PORT,
    'ports.joint2': _MOTOR_PORT,
    'ports.joint3': _MOTOR_PORT,
    'ports.gyro': _one_of('in1', 'in2', 'in3', 'in4'),
    'drivers.right_wheel': _nonempty_str,
    'drivers.left_wheel': _nonempty_str,
    'drivers.joint2': _nonempty_str,
    'drivers.joint3': _nonempty_str,
    'drivers.gyro': _nonempty_str,
    'stop_action': _one_of('coast', 'brake'),
    'polarity.right_wheel': _SIGN,
    'polarity.left_wheel': _SIGN,
    'polarity.joint2': _SIGN,
    'polarity.joint3': _SIGN,
    'gyro_sign': _SIGN,
    'wheel_radius_m': _number(0, 0.2),
    'start_pose_rad.th1': _number(-1.5, 1.5, lo_open=False),
    'start_pose_rad.th2': _number(-3.2, 3.2, lo_open=False),
    'start_pose_rad.th3': _number(-3.2, 3.2, lo_open=False),
    'limits.th1_rad': _number(0, 1.5),
    'limits.th2_rad': _number(0, 3.2),
    'limits.th3_rad': _number(0, 3.2),
    'limits.min_battery_v': _number(0, 10, lo_open=False),
    'limits.max_consecutive_overruns': _number(1, 1000, lo_open=False, integer=True),
    'filters.encoder_rate_cutoff_hz': _number(0, 1000),
    'filters.gyro_rate_cutoff_hz': _number(0, 1000),
    'filters.disturbance_cutoff_hz': _number(0, 1000, allow_null=True),
    'gyro_calibration.settle_s': _number(0, 10, lo_open=False),
    'gyro_calibration.duration_s': _number(0, 10),
    'gyro_calibration.max_rate_spread_dps': _number(0, 100, lo_open=False),
    'gyro_calibration.max_bias_dps': _number(0, 100, lo_open=False),
    'gyro_calibration.max_angle_change_deg': _number(0, 90, lo_open=False),
    'gyro_bias_time_constant_s': _number(0, 3600, allow_null=True),
    'gyro_bias_quiet_dps': _number(0, 100),
    'battery_period_s': _number(0, 60),
    'log_max_rows': _number(1, 1000000, lo_open=False, integer=True),
    'realtime_priority': _number(0, 99, lo_open=False, integer=True),
}


def _merge(base, override, source, prefix):
    """Copy of base with override's fields replacing base's; unknown fields are errors."""
    out = copy.deepcopy(base)
    for key in sorted(override):
        path = prefix + key
        if key not in base:
            raise ConfigError('{}: field {}: unknown field'.format(source, path))
        if isinstance(base[key], dict):
            if not isinstance(override[key], dict):
                raise ConfigError('{}: field {}: must be an object, got {!r}'.format(
                    source, path, override[key]))
            out[key] = _merge(base[key], override[key], source, path + '.')
        else:
            out[key] = copy.deepcopy(override[key])
    return out


def _leaves(doc, prefix=''):
    for key in sorted(doc):
        if isinstance(doc[key], dict):
            for item in _leaves(doc[key], prefix + key + '.'):
                yield item
        else:
            yield prefix + key, doc[key]


def validate(config, source):
    """Raise ConfigError naming source and field for the first problem found."""
    seen = set()
    for path, value in _leaves(config):
        check = SPEC.get(path)
        if check is None:
            raise ConfigError('{}: field {}: unknown field'.format(source, path))
        problem = check(value)
        if problem:
            raise ConfigError('{}: field {}: {}'.format(source, path, problem))
        seen.add(path)
    missing = sorted(set(SPEC) - seen)
    if missing:
        raise ConfigError('{}: field {}: missing'.format(source, missing[0]))
    ports = [config['ports'][m] for m in MOTORS]
    for i, m in enumerate(MOTORS):
        if ports.count(ports[i]) > 1:
            raise ConfigError('{}: field ports.{}: port {} is used by two motors'.format(
                source, m, ports[i]))


def motor_polarity(config):
    """The 4 motor polarities in motor order (right wheel, left wheel, joint 2, joint 3)."""
    return tuple(config['polarity'][m] for m in MOTORS)


def _read_json(path):
    try:
        with open(path, 'rb') as f:
            text = f.read().decode('utf-8')
    except (OSError, UnicodeError) as e:
        raise ConfigError('{}: cannot read: {}'.format(path, e))
    try:
        doc = json.loads(text)
    except ValueError as e:
        raise ConfigError('{}: not valid JSON: {}'.format(path, e))
    if not isinstance(doc, dict):
        raise ConfigError('{}: must be a JSON object'.format(path))
    return doc


def defaults():
    doc = _read_json(DEFAULT_PATH)
    validate(doc, DEFAULT_PATH)
    return doc


def config_from_overrides(overrides, source='<overrides>'):
    """Defaults with `overrides` (a dict shaped like the config, any subset) merged in."""
    merged = _merge(defaults(), overrides, source, '')
    validate(merged, source)
    return merged


def load_config(path=None):
    """The configuration: defaults, with the fields of the JSON file `path` (if given) replacing them."""
    if path is None:
        return defaults()
    return config_from_overrides(_read_json(path), path)
