"""The owner's experiments on the robot (issue 24): the fall test, the joint swing test and the
axle swing.

    python3 -m tipbot_fw fall-test [--log FILE] [--config FILE]
    python3 -m tipbot_fw swing-test --joint 1|2|3 [--log FILE] [--config FILE]

(under the supervisor, as the launcher runs a balance: ``python3 -m tipbot_fw.supervisor --
fall-test --config config.json``). All are short (the fall a few seconds, a joint swing 16 s, the
axle swing 23 s), drive only the joint motors (the axle swing the wheel motors too, open-loop),
within their duty limit and the configuration's joint limits, and write a log of the raw readings
and the duties (``kind`` ``fall`` or ``swing``; docs/log-format.md, "Experiment
logs") that the host fits (``python -m hostsim fit-robot``) and the pre-flight check reads
(``python3 -m tipbot_fw check --gains FILE --fall-log LOG``; tipbot_fw.preflight).

**The fall test.** The owner holds the robot still and upright on the floor, joints straight
(the start pose), with a soft stop (a cushion) ahead and behind. The gyro is calibrated as for a
run (tipbot_fw.calibration: still, 1.1 s), then LET GO: the joint motors hold the joints at the
start pose (a PD on their encoders), the wheel motors get no drive (duty 0), and the loop records
until the tilt passes ``--stop-deg`` (30 deg), where the fall is over and every motor stops; a
robot not let go within ``--timeout`` (6 s) stops the test (exit 4). The host (tipbot_fw.bodyfit)
fits the tilt's growth: the fall pole.

**The joint swing test.** Link 1 held still and upside down (on a stand, in a vice, or by a hand
braced on the table; ``HANGING``: the links above the joint hanging below it, gravity pulling
them back rather than away), the other joint held straight by its motor, the joint ``--joint``
follows a reference through a PD on its encoder: it leans the link (joint 2 0.15 rad, joint 3
0.3 rad) and swings it about there in whole sine cycles (0.3, 0.7 and 1.2 Hz; amplitudes 0.10,
0.08 and 0.05 rad on joint 2, 0.25, 0.20 and 0.12 rad on joint 3), then back; 0.35 rad off its
reference or beyond 0.7 rad it stops (the motor could not hold the link); the gyro watches link 1
(a turn faster than 30 deg/s for three ticks stops the test: link 1 was not held). The host fits
the joint's equation of motion with the motor's parameters: its lever (gravity torque) and inertia.

**The axle swing** (``--joint 1``). The owner holds the robot upside down by its two wheels (they
must not turn: a firm grip, or the tyres clamped), joints straight, the links hanging below the
axle; the gyro is calibrated while it hangs still. Hanging, gravity holds the robot, so the wheel
motors (their stators on link 1) drive it open-loop: a duty that leans it (``AXLE_SWING``: 50 %,
ramped in and out over ``SETTLE_S``) plus whole sine cycles (0.2, 0.5, 1.0 and 1.6 Hz, 21 s: below,
about and above the hanging robot's own swing, 0.9-1.5 Hz), never crossing zero, so that the wheel
gears stay on one side of their 3 deg of free play and the wheel encoders (the wheels held: minus
link 1's angle) read link 1's turn. The joints are held straight by their PD. Beyond 0.7 rad from hanging straight
down it stops (exit 6). The host fits the robot's lever about the axle a1 = M h and its inertia
there (with the two wheel motors' model): the one lever the fall (a ratio) and the joint swings do
not give. At 8 V the two Large motors give 0.47 N m at full duty: the lean peaks at 0.1 rad for a
robot of twice the paper's lever, at 0.3 rad for half of it.

Safety as in every command that drives motors (tipbot_fw.guard.safety.run_guarded): signals become
exceptions, whatever ends the test the motors are stopped first, then the log is written. A joint
beyond ``limits.th2_rad``/``th3_rad`` stops it (exit 6); a failed read exit 5; low battery exit 4.
Python 3.5 and numpy 1.12 (the brick's).
"""
import array
import math
import sys
import time

import tipbot_fw
from tipbot_fw.record import logfile
from tipbot_fw.calibration import calibrate_gyro
from tipbot_fw.console import say as _say
from tipbot_fw.guard.heartbeat import NOT_SUPERVISED
from tipbot_fw.guard.plausibility import check_battery
from tipbot_fw.session import BeatingClock
from tipbot_fw.guard.exit_codes import EXIT_ERROR, EXIT_OK, EXIT_REFUSED
from tipbot_fw.guard.safety import DeviceFailure, JointLimit, LowBattery, SafetyStop, run_guarded, watchdog_stop

KINDS = ('fall', 'swing')
EXPERIMENT_VERSION = 1
COLUMNS = (('time_s', 's'),            # from the let-go cue (fall) or the swing's start
           ('enc_r', 'count'), ('enc_l', 'count'), ('enc_2', 'count'), ('enc_3', 'count'),
           ('gyro_angle', 'deg'), ('gyro_rate', 'deg/s'),      # raw, the sensor's sign
           ('duty_r', '%'), ('duty_l', '%'), ('duty_2', '%'), ('duty_3', '%'),   # written this tick
           ('battery_v', 'V'),
           ('ref_rad', 'rad'))         # the swung joint's reference (0 in a fall)
COLUMN_NAMES = tuple(c[0] for c in COLUMNS)
N_COLUMNS = len(COLUMNS)

PERIOD_S = 0.005
DEG = math.pi / 180.0
# The joint PD (percent duty per rad, per rad/s), held or swung, per joint: above the gravity
# stiffness of links up to twice the paper's (joint 2: 2 x 0.62 N m/rad on 0.036 N m/V at
# 8 V = 430 %/rad; joint 3: 2 x 0.10 on 0.014 N m/V, 180 %/rad), below what the 1-degree
# encoder's steps make chatter at 5 ms; joint 3's held stiffly enough that its link bends by
# gravity less than a tenth of link 2's swing (0.1 N m/rad of gravity against 0.9 N m/rad).
JOINT_KP = {2: 700.0, 3: 800.0}
JOINT_KD = {2: 30.0, 3: 10.0}
DUTY_LIMIT = 100
# The rate estimate of the PD: counts over this many ticks (a 1-count step in one tick is 3.5 rad/s)
RATE_TICKS = 4
# The swing's reference per joint: a centre it moves to (and back from) in SETTLE_S, then whole
# sine cycles (frequency Hz, amplitude rad, cycles) about it; low frequencies show the gravity
# torque, high ones the inertia. The centre keeps the link leaning one way throughout, so that
# gravity holds it on one side of its gear's free play (3 deg on a Large motor, which the encoder,
# on the rotor's side, does not see: a swing through upright crosses it at every turn and reads a
# lever 15 % too large).
# Joint 3 swings far (0.05-0.55 rad): its lever is read from how gravity's torque g a3 sin(angle)
# varies over the swing (the fit's constant takes its mean), against the Medium motor's friction
# (18 mN m, 10 % duty at 8 V) and its 1-degree counts. Link 3's g a3 is 0.1 N m/rad (the paper's):
# the old swing (0.02-0.22 rad) varied it by 0.02 N m and read a3 to -20..+13 % over the owners'
# study's robots; this one by 0.05 N m, -6..0 % (docs/your-robot.md). Its torque, 0.05 N m on the
# paper's link 3 and 0.11 on one of twice its lever, stays within the Medium motor's 0.11 N m at
# full duty at 8 V, hanging only: upright the same swing lost two heavy links of the 20.
SWING = {2: (0.15, ((0.3, 0.10, 2), (0.7, 0.08, 3), (1.2, 0.05, 4))),
         3: (0.30, ((0.3, 0.25, 2), (0.7, 0.20, 3), (1.2, 0.12, 4)))}
# The swings are done with the robot upside down (link 1 held, the links above the joint hanging
# below it). Upright, gravity pulls the links away from their reference with a stiffness g a
# (joint 2: 0.62 N m/rad for the paper's links 2 and 3, up to 1.2 on an owner's heavier ones) that
# the PD's 2 N m/rad only halves: a heavy pair sits twice as far out as its reference or more and
# takes more than the Large motor's 0.28 N m beyond 0.25 rad, where nothing stops it falling
# further. Hanging, gravity restores: the same PD holds the links within their reference (0.7-0.9
# of it), the motor's torque g a sin(angle) stays within its reach on the heaviest, and a motor
# short of torque lets them swing back towards hanging, never away. The lean keeps gravity's
# torque, hence the gear, on one side. Joint 3's swing, larger, needs it as much as joint 2's, and
# the owner holds the robot once for both.
HANGING = {2: True, 3: True}
# The axle swing's wheel duty (percent, both motors, model direction): a lean, then sine cycles
# (Hz, amplitude %, cycles) about it, smaller where the hanging robot swings by itself (about
# 1.2 Hz for the paper's robot); lean minus amplitude stays above 0 (the gears on one side of their
# play), lean plus amplitude within 100 %. The low frequencies give the lever (gravity's torque
# against the motors'), the high ones the inertia.
AXLE_SWING = (50.0, ((0.2, 45.0, 2), (0.5, 35.0, 3), (1.0, 20.0, 3), (1.6, 20.0, 4)))
# Beyond this the swung link has got away (a joint-2 motor holds the paper's links 2 and 3 only to
# about 0.45 rad: 0.28 N m at 8 V against 0.62 N m x sin(angle)): stop before it falls further
SWING_LIMIT_RAD = 0.7
SETTLE_S = 0.5        # held at the start pose before the swing and after it
DEFAULTS = {'stop_deg': 30.0, 'timeout_s': 6.0}
# Link 1 not held during a swing: its rate beyond this for this many ticks in a row (the gyro's
# angle drifts by its bias, a degree a second, too much to watch over a 12 s swing)
HOLD_RATE_DPS = 30
HOLD_TICKS = 3


class NotReleased(SafetyStop):
    reason = 'not_released'
    exit_code = EXIT_REFUSED


class NotHeld(SafetyStop):
    reason = 'not_held'
    exit_code = EXIT_REFUSED


def _smoothstep(x):
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


def swing_reference(t, joint):
    """(reference, its rate) of the swung joint (rad, rad/s, from its start pose) at t seconds
    after the swing's start; None after its end."""
    centre, segments = SWING[joint]
    if t < SETTLE_S:
        f, df = _smoothstep(t / SETTLE_S)
        return centre * f, centre * df / SETTLE_S
    t -= SETTLE_S
    for hz, amp, cycles in segments:
        span = cycles / hz
        if t < span:
            w = 2.0 * math.pi * hz
            return centre + amp * math.sin(w * t), amp * w * math.cos(w * t)
        t -= span
    if t < SETTLE_S:
        f, df = _smoothstep(1.0 - t / SETTLE_S)
        return centre * f, -centre * df / SETTLE_S
    return (0.0, 0.0) if t < 2 * SETTLE_S else None


def swing_duration_s(joint):
    segments = AXLE_SWING[1] if joint == 1 else SWING[joint][1]
    return 3 * SETTLE_S + sum(c / hz for hz, _, c in segments)


def axle_duty(t):
    """The axle swing's wheel duty (percent, model direction, not rounded) at t seconds after its
    start; None after its end."""
    lean, segments = AXLE_SWING
    if t < SETTLE_S:
        return lean * _smoothstep(t / SETTLE_S)[0]
    t -= SETTLE_S
    for hz, amp, cycles in segments:
        span = cycles / hz
        if t < span:
            return lean + amp * math.sin(2.0 * math.pi * hz * t)
        t -= span
    if t < SETTLE_S:
        return lean * _smoothstep(1.0 - t / SETTLE_S)[0]
    return 0.0 if t < 2 * SETTLE_S else None


def axle_angle(config, counts_per_rot, zero_counts, enc):
    """Link 1's turn (rad, from where it hung at the start) from the wheel encoders' raw counts: the
    wheels held, minus their mean angle relative to link 1."""
    pol = config['polarity']
    return -0.5 * sum(pol[role] * 2.0 * math.pi / counts_per_rot[i] * (enc[i] - zero_counts[i])
                      for i, role in ((0, 'right_wheel'), (1, 'left_wheel')))


class Joints(object):
    """The joints' angles (rad, from the start pose) from raw counts, and their PD."""

    def __init__(self, config, counts_per_rot, zero_counts):
        pol = config['polarity']
        self.k = (pol['joint2'] * 2.0 * math.pi / counts_per_rot[2], pol['joint3'] * 2.0 * math.pi / counts_per_rot[3])
        self.sign = (pol['joint2'], pol['joint3'])
        self.zero = (zero_counts[2], zero_counts[3])
        self.zero_counts = tuple(zero_counts)
        self.limits = (config['limits']['th2_rad'], config['limits']['th3_rad'])
        pose = config['start_pose_rad']
        self.pose = (pose['th2'], pose['th3'])
        self.history = []

    def angles(self, enc):
        return ((enc[2] - self.zero[0]) * self.k[0], (enc[3] - self.zero[1]) * self.k[1])

    def duties(self, enc, refs, rates=(0.0, 0.0)):
        """The two joint motors' duties (signed for the motor) that hold/swing them to refs
        (moving at rates)."""
        ang = self.angles(enc)
        for i in (0, 1):
            if abs(self.pose[i] + ang[i]) > self.limits[i]:
                raise JointLimit('joint {} at {:.2f} rad, beyond limits.th{}_rad = {}'.format(
                    i + 2, self.pose[i] + ang[i], i + 2, self.limits[i]))
        self.history.append(ang)
        old = self.history[0]
        if len(self.history) > RATE_TICKS:
            self.history.pop(0)
        span = max(len(self.history) - 1, 1) * PERIOD_S
        out = []
        for i, joint in ((0, 2), (1, 3)):
            rate = (ang[i] - old[i]) / span
            d = JOINT_KP[joint] * (refs[i] - ang[i]) + JOINT_KD[joint] * (rates[i] - rate)
            d = int(round(max(-DUTY_LIMIT, min(DUTY_LIMIT, d))))
            out.append(self.sign[i] * d)
        return out


def write_experiment_log(path, header, rows):
    """An experiment log: the run log's container with COLUMNS (tipbot_fw.record.logfile.read_log reads it)."""
    import numpy as np    # late: the experiment's loop does not need it
    body = np.frombuffer(array.array('d', rows).tobytes(), dtype='=f8')
    logfile.write_log(path, header, body.reshape(-1, N_COLUMNS), columns=COLUMNS)


def run_experiment(kind, devices, clock, config, joint=None, log_path=None, say=_say, heartbeat=NOT_SUPERVISED,
                   guard=None, stop_deg=DEFAULTS['stop_deg'], timeout_s=DEFAULTS['timeout_s'],
                   cue=None):
    """The fall test (kind 'fall') or the swing test of ``joint`` (kind 'swing'). -> (exit code,
    log header). Never raises; the motors are stopped on every exit, then the log written.
    cue(text): tells the owner what to do (default: say)."""
    cue = say if cue is None else cue
    header = {
        'kind': kind, 'experiment_version': EXPERIMENT_VERSION,
        'versions': {'python': sys.version.split()[0], 'tipbot_fw': tipbot_fw.__version__},
        'start_wall_time_s': time.time(),
        'start_wall_time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        'config': config, 'counts_per_rot': list(devices.counts_per_rot), 'period_s': PERIOD_S,
        'joint': joint, 'joint_kp_pct_per_rad': JOINT_KP, 'joint_kd_pct_s_per_rad': JOINT_KD,
        'supervised': heartbeat.supervised,
    }
    if kind == 'fall':
        header.update(stop_deg=stop_deg, timeout_s=timeout_s)
    elif joint == 1:
        header.update(axle_lean_pct=AXLE_SWING[0], axle_segments=[list(s) for s in AXLE_SWING[1]], settle_s=SETTLE_S)
    else:
        header.update(hold_rate_dps=HOLD_RATE_DPS, swing_centre_rad=SWING[joint][0],
                      swing_segments=[list(s) for s in SWING[joint][1]], settle_s=SETTLE_S,
                      hanging=HANGING[joint])
    rows = array.array('d')
    state = {}

    def body():
        bv = devices.read_battery_v()
        header['battery_v_start'] = bv
        check_battery(bv)
        if bv < config['limits']['min_battery_v']:
            raise LowBattery('battery at {:.2f} V is below limits.min_battery_v = {} V: charge it'.format(
                bv, config['limits']['min_battery_v']))
        cal_config = config['gyro_calibration']
        if kind == 'fall':
            cue('HOLD the robot still and upright on the floor, joints straight, a cushion ahead and behind: '
                'calibrating the gyro ({:.1f} s)'.format(cal_config['settle_s'] + cal_config['duration_s']))
        elif joint == 1:
            cue('HOLD the robot upside down by both wheels, firmly (they must not turn), joints straight, links '
                'hanging: the wheel motors will swing it to and fro on one side for {:.0f} s, then go limp; '
                'calibrating the gyro (hold it still)'.format(swing_duration_s(joint)))
        else:
            centre, segments = SWING[joint]
            cue('HOLD link 1 still and {} (a stand or a vice), wheels free: joint {} will lean its link '
                'by {:.0f} deg and swing it by up to {:.0f} deg about there for {:.0f} s, then the joints '
                'go limp ({}); calibrating the gyro'.format(
                    'UPSIDE DOWN, the links hanging below it' if HANGING[joint] else 'upright', joint, centre / DEG,
                    max(a for _, a, _ in segments) / DEG, swing_duration_s(joint),
                    'they fall back to hanging' if HANGING[joint] else 'catch the links'))
        heartbeat.arm()
        cal = calibrate_gyro(devices, BeatingClock(clock, heartbeat), PERIOD_S, cal_config)
        header['calibration'] = cal.as_dict()
        enc, _ = _read(devices)
        header['zero_counts'] = list(enc)
        joints = Joints(config, devices.counts_per_rot, enc)
        if kind == 'fall':
            cue('LET GO NOW: let it fall onto the cushion')
        _loop(kind, joint, devices, clock, config, joints, cal.gyro_bias_dps, bv, rows, heartbeat,
              stop_deg, timeout_s, state)

    def stop_motors():
        failures = devices.stop_all()
        heartbeat.disarm()
        return failures

    def finish(reason, code, msg):
        header.update(stop_reason=reason, stop_message=msg, exit_code=code, stop_wall_time_s=time.time(),
                      rows=len(rows) // N_COLUMNS, ended=state.get('ended'))
        note = 'no log written'
        if log_path and len(rows):
            try:
                write_experiment_log(log_path, header, rows)
                note = 'log {}'.format(log_path)
            except Exception as e:      # the motors are stopped: report, never raise
                say('could not write the log {}: {!r}'.format(log_path, e))
                if code == EXIT_OK:
                    code = header['exit_code'] = EXIT_ERROR
        say('stopped: {} (exit {}, {} ticks{}); {}'.format(msg, code, header['rows'],
                                                          ', ' + state['ended'] if state.get('ended') else '', note))
        return code, header

    return run_guarded(body, stop_motors, finish, say, guard)


def _read(devices):
    try:
        return devices.read_raw()
    except (OSError, ValueError) as e:
        raise DeviceFailure('read failed: {}'.format(e))


def _loop(kind, joint, devices, clock, config, joints, bias_dps, battery_v, rows, heartbeat, stop_deg, timeout_s,
          state):
    """The experiment's ticks, every PERIOD_S from now, until its end (state['ended'])."""
    gyro_sign = config['gyro_sign']
    swung = None if kind == 'fall' or joint == 1 else joint - 2
    axle = kind == 'swing' and joint == 1
    pol = config['polarity']
    t0 = clock.now()
    k = 0
    angle0 = None
    moving = 0
    end_s = timeout_s if kind == 'fall' else swing_duration_s(joint) + 1.0
    while True:
        t = clock.now() - t0
        enc, (angle, rate) = _read(devices)
        if angle0 is None:
            angle0 = angle
        tilt_deg = gyro_sign * (angle - angle0) - bias_dps * t       # link 1's tilt since the start
        ref = 0.0
        refs, rates = [0.0, 0.0], [0.0, 0.0]
        d_r = d_l = 0
        if axle:
            duty = axle_duty(t)
            if duty is None:
                state['ended'] = 'swing done'
                return
            d_r, d_l = pol['right_wheel'] * int(round(duty)), pol['left_wheel'] * int(round(duty))
        elif swung is not None:
            at = swing_reference(t, joint)
            if at is None:
                state['ended'] = 'swing done'
                return
            ref = refs[swung] = at[0]
            rates[swung] = at[1]
        d2, d3 = joints.duties(enc, refs, rates)
        if kind == 'swing':
            away = joints.angles(enc)[swung] if not axle else axle_angle(config, devices.counts_per_rot,
                                                                           joints.zero_counts, enc)
            if axle and abs(away) > SWING_LIMIT_RAD:
                raise JointLimit('the robot swung to {:.2f} rad from hanging, beyond the swing\'s {} rad: were the '
                                 'wheels held and the robot hanging?'.format(away, SWING_LIMIT_RAD))
            if not axle and (abs(away - ref) > SWING_LIMIT_RAD / 2 or abs(away) > SWING_LIMIT_RAD):
                raise JointLimit('joint {} swung to {:.2f} rad, beyond the swing\'s {} rad: its motor could not hold '
                                 'the link (too heavy, or link 1 not held {}?)'.format(
                                     joint, away, SWING_LIMIT_RAD, 'upside down' if HANGING[joint] else 'upright'))
        duties = [d_r, d_l, d2, d3]
        try:
            devices.write_duties(duties)
        except (OSError, ValueError) as e:
            raise DeviceFailure('write failed: {}'.format(e))
        rows.extend((t,) + tuple(enc) + (angle, rate) + tuple(duties) + (battery_v, ref))
        heartbeat.beat(k)
        if k % 40 == 0:
            stop = watchdog_stop(heartbeat)
            if stop is not None:
                raise stop
        if kind == 'fall':
            if abs(tilt_deg) >= stop_deg:
                state['ended'] = 'fell past {:.0f} deg'.format(stop_deg)
                return
            if t > timeout_s:
                raise NotReleased('the robot did not fall within {:.0f} s of the LET GO cue: let go of it '
                                  'when told (or give it a nudge)'.format(timeout_s))
        elif axle:
            pass        # link 1 swings: the gyro has nothing to watch
        elif abs(gyro_sign * rate - bias_dps) > HOLD_RATE_DPS:
            moving += 1
            if moving >= HOLD_TICKS:
                raise NotHeld('link 1 turned at {:.0f} deg/s during the swing (more than {} deg/s for {} ticks): '
                              'hold it still, on a stand or in a vice'.format(gyro_sign * rate - bias_dps,
                                                                              HOLD_RATE_DPS, HOLD_TICKS))
        else:
            moving = 0
        if kind == 'swing' and t > end_s:
            state['ended'] = 'swing done'
            return
        k += 1
        clock.sleep_until(t0 + k * PERIOD_S)


# ---------------------------------------------------------------------------- command line
def add_arguments(sp, kind):
    """The fall-test / swing-test subcommand's options (tipbot_fw.cli adds --config, --sysfs-root)."""
    if kind == 'swing':
        sp.add_argument('--joint', type=int, choices=(1, 2, 3), required=True,
                        help='the joint whose motor swings its link (1: the wheel motors swing the whole robot, '
                        'hanging upside down from its held wheels)')
    else:
        sp.add_argument('--stop-deg', type=float, default=DEFAULTS['stop_deg'],
                        help='the fall is over (motors stopped) at this tilt (default {:g} deg)'.format(
                            DEFAULTS['stop_deg']))
    sp.add_argument('--log', metavar='FILE', help='experiment log (default {}-YYYYmmdd-HHMMSS.log in logs/ if the '
                    'current directory holds tipbot_fw/, else in the current directory)'.format(kind))


def main_experiment(kind, args, config, devices, heartbeat=NOT_SUPERVISED, clock=None):
    """The fall-test and swing-test subcommands (tipbot_fw.cli). -> exit code."""
    from tipbot_fw.io.clock import MonotonicClock
    name = kind if kind == 'fall' else 'swing{}'.format(args.joint)
    log_path = args.log or logfile.default_path(name)
    stop = getattr(args, 'stop_deg', DEFAULTS['stop_deg'])
    if not 5.0 <= stop <= 60.0:
        _say('refused to start: --stop-deg must be in [5, 60] deg, got {}'.format(stop))
        return EXIT_REFUSED
    code, _ = run_experiment(kind, devices, clock or MonotonicClock(), config, joint=getattr(args, 'joint', None),
                             log_path=log_path, heartbeat=heartbeat, stop_deg=stop)
    return code
