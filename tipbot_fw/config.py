"""Robot configuration: defaults in default_config.json, overridden field by field by --config.

Every field is validated; errors name the file and the dotted field path. Fields (SI units):

  ports.{right_wheel,left_wheel,joint2,joint3}  motor port, outA..outD, all different
  ports.gyro                                   sensor port, in1..in4
  ports.ir_remote                              the IR sensor's port (in1..in4), or null (the default):
                                               run without --course or --remote drives by the EV3 IR
                                               remote's buttons (tipbot_fw.drive.ir_remote)
  ir_remote_channel                            the remote's channel (its red slider), 1..4
  drivers.<device>                             expected driver name (checked by the device layer)
  estimator                                    kalman (the default: tipbot_fw.cores.kalman) or detector (the
                                               paper's Section 6 robust detector: tipbot_fw.cores.detector_core)
  stop_action                                  what a stopped motor does: coast or brake
  polarity.<motor>                             +1/-1: multiplies the measured counts AND the duty
  gyro_sign                                    +1/-1: +1 if a positive gyro rate is a forward tilt
  wheel_radius_m                               wheel radius R_w of the detector's signal chain (the
                                               Kalman filter uses its gains file's, the model's)
  start_pose_rad.{th1,th2,th3}                 pose the robot is held in at start (th1 integrates
                                               from it; th2, th3 are the joint encoders' zeros)
  limits.th1_rad, limits.th2_rad, limits.th3_rad   |angle| beyond -> motors stopped in that tick
  limits.min_battery_v                         refuse to start below this battery voltage
  limits.warn_battery_v                        warn (words, light, tone) when a reading while
                                               balancing is below this voltage
  limits.overrun_window_s                      the sliding window the overrun stop looks back over
  limits.max_lost_s                            time lost to late ticks within that window (whole
                                               periods skipped x period, plus the current tick's
                                               lateness) beyond which the loop is behind -> safe
                                               stop (tipbot_fw.loop; docs/architecture.md); the
                                               window's longest single hold is left out of it
  limits.max_stall_s                           the longest single stall ridden out: the supervisor
                                               holds a frozen controller's last duties that long,
                                               then stops the motors; a loop back from a longer
                                               stall stops (docs/architecture.md: the loop's timing)
  limits.max_saturated_s                       a motor whose duty sits at its saturation in 90 % of
                                               the ticks of this long stops the run (exit 6): the
                                               law saturates only for a moment while it balances,
                                               so the robot is lost (fallen while a sensor stopped,
                                               running away on an encoder that stopped counting,
                                               blocked or held) (tipbot_fw.loop)
  (limits.max_consecutive_overruns             the stop of earlier versions: still accepted in a
                                               config file, with a note, and not used)
  filters.encoder_rate_cutoff_hz               detector only: low-pass of the differentiated encoder positions
  filters.gyro_rate_cutoff_hz                  detector only: low-pass of the gyro rate (th1_dot)
  filters.disturbance_cutoff_hz                detector only: low-pass of the disturbance estimate w^
                                               before the law uses it (tipbot_fw.cores.detector); null = none
  gyro_calibration.settle_s                    gyro samples read and not used at start (the first
                                               ones after the mode switch may be the old mode's)
  gyro_calibration.duration_s                  then the stillness window for the bias
  gyro_calibration.max_rate_spread_dps         max - min rate allowed in that window
  gyro_calibration.max_bias_dps                largest |mean rate| taken for a bias (more: turning)
  gyro_calibration.max_angle_change_deg        angle change allowed in that window beyond the
                                               drift the mean rate explains (tipbot_fw.calibration)
  gyro_bias_time_constant_s                    detector only: slow bias tracking while running; null =
                                               off (the default: see tipbot_fw.cores.signal_chain for why); the
                                               Kalman filter estimates the bias itself
  gyro_bias_quiet_dps                          detector only: the tracking learns only from samples
                                               whose corrected rate is within +- this (at rest)
  battery_period_s                             battery re-read period (outside the ticks)
  log_max_rows                                 rows the log file holds at most (its size: 232 bytes
                                               a row for the Kalman core): a longer run keeps its
                                               first log_head_rows and its last ones, the ticks
                                               between are counted, not recorded
  log_head_rows                                the first rows of a run always kept (calibration,
                                               start), at most half of log_max_rows, whole chunks
                                               of 50; 0: only the last ones
  realtime_priority                            SCHED_FIFO priority to request, 0 = don't
"""
import copy
import os

from tipbot_fw import fields
from tipbot_fw.vocabulary import MOTOR_ROLES

DEFAULT_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'default_config.json')

# The ev3dev sysfs tree; TIPBOT_SYSFS_ROOT names another (a fake EV3 behind the launcher: make
# sim-brick), --sysfs-root one for a single command.
SYSFS_ROOT = '/sys/class'
SYSFS_ROOT_ENV = 'TIPBOT_SYSFS_ROOT'


def default_sysfs_root(environ=None):
    return (os.environ if environ is None else environ).get(SYSFS_ROOT_ENV) or SYSFS_ROOT


class ConfigError(ValueError):
    """Invalid configuration; the message names the file and the field."""


_number = fields.number
_one_of = fields.one_of
_SIGN = _one_of(1, -1)
_MOTOR_PORT = _one_of('outA', 'outB', 'outC', 'outD')

# The overrun stop's bounds. The window: from a few periods to 2 s (longer, a loop that is
# behind goes on for seconds before it is stopped). The lost time: more than 0.1 s is beyond any
# gains' delay margin (docs/realistic-brick.md, margins: 33 ms paper, 52 ms physical), and at most half the window
# (a larger budget lets a loop that runs at half the rate go on for ever).
OVERRUN_WINDOW_S = (0.02, 2.0)
MAX_LOST_S = 0.1
# The single-stall ride-out (docs/architecture.md, the loop's timing): above the stalls a
# loaded brick shows (10-30 ms, 87 ms seen), below the 180-316 ms the physical gains ride out
# (margins). Bounds: a stall shorter than 4 periods is an ordinary late tick; one of 0.5 s is
# beyond any three-link robot's recovery (its unstable pole, about 10/s, grows an error e^5 =
# 150 times in that time).
MAX_STALL_S = 0.15
MAX_STALL_BOUNDS_S = (0.02, 0.5)
# The saturation stop (tipbot_fw.loop): a motor at its duty limit in SATURATED_SHARE of the ticks
# of limits.max_saturated_s. The law saturates while it catches a push or a stall (on the realistic
# brick at most 16 % of any second's ticks in the runs that stood, 35 % in a push that felled the
# robot); a motor held there for a whole second is a robot that no longer balances. Bounds: not shorter than a push's
# recovery, not longer than the owner would let a robot drive blind.
MAX_SATURATED_S = 1.0
MAX_SATURATED_BOUNDS_S = (0.25, 5.0)
SATURATED_SHARE = 0.9
# The stop of earlier versions (late ticks in a row): its old bounds, for the files that still have it.
DEPRECATED_LIMITS = {'max_consecutive_overruns': _number(1, 100, lo_open=False, integer=True)}

# Leaf validators by dotted path; the set of paths is also the set of allowed fields.
SPEC = {
    'ports.right_wheel': _MOTOR_PORT,
    'ports.left_wheel': _MOTOR_PORT,
    'ports.joint2': _MOTOR_PORT,
    'ports.joint3': _MOTOR_PORT,
    'ports.gyro': _one_of('in1', 'in2', 'in3', 'in4'),
    'ports.ir_remote': _one_of(None, 'in1', 'in2', 'in3', 'in4'),
    'ir_remote_channel': _one_of(1, 2, 3, 4),
    'drivers.right_wheel': fields.nonempty_string,
    'drivers.left_wheel': fields.nonempty_string,
    'drivers.joint2': fields.nonempty_string,
    'drivers.joint3': fields.nonempty_string,
    'drivers.gyro': fields.nonempty_string,
    'drivers.ir_remote': fields.nonempty_string,
    'estimator': _one_of('kalman', 'detector'),
    'stop_action': _one_of('coast', 'brake'),
    'polarity.right_wheel': _SIGN,
    'polarity.left_wheel': _SIGN,
    'polarity.joint2': _SIGN,
    'polarity.joint3': _SIGN,
    'gyro_sign': _SIGN,
    'wheel_radius_m': _number(0.005, 0.1),      # LEGO wheels: radius 8 mm to 47 mm
    'start_pose_rad.th1': _number(-1.5, 1.5, lo_open=False),
    'start_pose_rad.th2': _number(-3.2, 3.2, lo_open=False),
    'start_pose_rad.th3': _number(-3.2, 3.2, lo_open=False),
    'limits.th1_rad': _number(0, 1.5),
    'limits.th2_rad': _number(0, 3.2),
    'limits.th3_rad': _number(0, 3.2),
    'limits.min_battery_v': _number(5.0, 9.0, lo_open=False),   # within what a battery reads (plausibility)
    'limits.warn_battery_v': _number(5.0, 9.0, lo_open=False),  # and not below min_battery_v: validate()
    'limits.overrun_window_s': _number(OVERRUN_WINDOW_S[0], OVERRUN_WINDOW_S[1], lo_open=False),
    'limits.max_lost_s': _number(0, MAX_LOST_S),
    'limits.max_stall_s': _number(MAX_STALL_BOUNDS_S[0], MAX_STALL_BOUNDS_S[1], lo_open=False),
    'limits.max_saturated_s': _number(MAX_SATURATED_BOUNDS_S[0], MAX_SATURATED_BOUNDS_S[1], lo_open=False),
    'filters.encoder_rate_cutoff_hz': _number(0.5, 500, lo_open=False),   # and below Nyquist: check_config_against_gains
    'filters.gyro_rate_cutoff_hz': _number(0.5, 500, lo_open=False),
    'filters.disturbance_cutoff_hz': _number(0.01, 100, lo_open=False, allow_null=True),
    'gyro_calibration.settle_s': _number(0, 10, lo_open=False),
    'gyro_calibration.duration_s': _number(0.01, 10, lo_open=False),
    'gyro_calibration.max_rate_spread_dps': _number(0, 100, lo_open=False),
    'gyro_calibration.max_bias_dps': _number(0, 100, lo_open=False),
    'gyro_calibration.max_angle_change_deg': _number(0, 90, lo_open=False),
    'gyro_bias_time_constant_s': _number(1, 3600, lo_open=False, allow_null=True),
    'gyro_bias_quiet_dps': _number(0, 100),
    'battery_period_s': _number(0.1, 10, lo_open=False),
    'log_max_rows': _number(1, 720000, lo_open=False, integer=True),   # 1 h at 5 ms: 170 MB of file (Kalman)
    'log_head_rows': _number(0, 720000, lo_open=False, integer=True),  # capped at log_max_rows / 2
    'realtime_priority': _number(0, 98, lo_open=False, integer=True),  # the supervisor takes one above
}


def _merge(base, override, f, prefix):
    """Copy of base with override's fields replacing base's; unknown fields are errors."""
    out = copy.deepcopy(base)
    f.known(override, base, prefix)
    for key in sorted(override):
        if isinstance(base[key], dict):
            f.check(prefix + key, override[key], fields.obj)
            out[key] = _merge(base[key], override[key], f, prefix + key + '.')
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


def validate(config, source, error=ConfigError, prefix=''):
    """Raise error (ConfigError) naming source and field (after prefix) for the first problem found."""
    f = fields.Fields(source, error, prefix)
    leaves = dict(_leaves(config))
    f.known(leaves, SPEC)
    f.require(leaves, sorted(SPEC))
    for path in sorted(leaves):
        f.check(path, leaves[path], SPEC[path])
    ports = [config['ports'][m] for m in MOTOR_ROLES]
    for i, m in enumerate(MOTOR_ROLES):
        if ports.count(ports[i]) > 1:
            f.fail('ports.' + m, 'is {}, the port of another motor too'.format(ports[i]))
    if config['ports']['ir_remote'] == config['ports']['gyro']:
        f.fail('ports.ir_remote', 'is {}, the gyro\'s port too'.format(config['ports']['gyro']))
    lim = config['limits']
    if lim['warn_battery_v'] < lim['min_battery_v']:    # a warning the next start would refuse to run with
        f.fail('limits.warn_battery_v', 'is {!r} V, below limits.min_battery_v = {!r} V: the warning would come '
               'after the battery is too low to start again'.format(lim['warn_battery_v'], lim['min_battery_v']))
    if lim['max_lost_s'] > 0.5 * lim['overrun_window_s']:
        f.fail('limits.max_lost_s', 'is {!r} s, more than half of limits.overrun_window_s = {!r} s: a loop running '
               'at half its rate would never be stopped'.format(lim['max_lost_s'], lim['overrun_window_s']))
    for j in ('th1', 'th2', 'th3'):     # a start beyond the stop limits would be a "fall" at tick 0
        pose, limit = config['start_pose_rad'][j], config['limits'][j + '_rad']
        if abs(pose) >= limit:
            f.fail('start_pose_rad.' + j, 'is {!r} rad, beyond limits.{}_rad = {!r}: the run would stop at its first '
                   'tick'.format(pose, j, limit))


# How far the configured wheel radius may be from the one the gains were designed for.
WHEEL_RADIUS_RTOL = 0.05


def check_config_against_gains(config, gains, source):
    """What a configuration must agree on with the gains file it runs: filter cut-offs below the
    Nyquist frequency of the gains' period, and the wheel radius the gains' model was made for
    (its recorded parameters, when there are any). ConfigError naming source and field."""
    f = fields.Fields(source, ConfigError)
    nyquist = 0.5 / gains.ts_s
    for name in ('encoder_rate_cutoff_hz', 'gyro_rate_cutoff_hz', 'disturbance_cutoff_hz'):
        v = config['filters'][name]
        if v is not None and v >= nyquist:
            f.fail('filters.' + name, 'is {!r} Hz, not below the Nyquist frequency {:g} Hz of the gains\' period '
                   '{} s'.format(v, nyquist, gains.ts_s))
    rw = (getattr(gains, 'parameters', None) or {}).get('rw_m')
    if fields.is_number(rw) and rw > 0 and abs(config['wheel_radius_m'] - rw) > WHEEL_RADIUS_RTOL * rw:
        f.fail('wheel_radius_m', 'is {!r} m, but the gains {} were designed for wheels of radius {!r} m'.format(
            config['wheel_radius_m'], gains.path, rw))


def motor_polarity(config):
    """The 4 motor polarities in motor order (right wheel, left wheel, joint 2, joint 3)."""
    return tuple(config['polarity'][m] for m in MOTOR_ROLES)


def defaults():
    doc = fields.read_object(DEFAULT_PATH, ConfigError)
    validate(doc, DEFAULT_PATH)
    return doc


def _drop_deprecated(overrides, f, notes):
    """overrides without the fields of earlier versions (validated as they were), a note for each
    in `notes`: an owner's config.json keeps loading."""
    limits = overrides.get('limits') if isinstance(overrides, dict) else None
    if not isinstance(limits, dict) or not set(limits) & set(DEPRECATED_LIMITS):
        return overrides
    out = dict(overrides, limits=dict(limits))
    for key in sorted(set(limits) & set(DEPRECATED_LIMITS)):
        f.check('limits.' + key, limits[key], DEPRECATED_LIMITS[key])
        del out['limits'][key]
        notes.append('{}: field {}limits.{} is no longer used (the overrun stop is now limits.max_lost_s within '
                     'limits.overrun_window_s; see docs/realistic-brick.md): ignored'.format(f.source, f.prefix, key))
    return out


def config_from_overrides(overrides, source='<overrides>', error=ConfigError, prefix='', notes=None):
    """Defaults with `overrides` (a dict shaped like the config, any subset) merged in; a bad field
    raises error naming source and the field after prefix (a scenario's firmware_config:
    hostsim.sim.scenario). A field of an earlier version is dropped with a note appended to
    `notes` (a list, or None: not kept)."""
    f = fields.Fields(source, error, prefix)
    overrides = _drop_deprecated(overrides, f, [] if notes is None else notes)
    merged = _merge(defaults(), overrides, f, '')
    validate(merged, source, error, prefix)
    return merged


def load_config(path=None, notes=None):
    """The configuration: defaults, with the fields of the JSON file `path` (if given) replacing them
    (notes: as config_from_overrides)."""
    if path is None:
        return defaults()
    return config_from_overrides(fields.read_object(path, ConfigError), path, notes=notes)
