"""Command line: python3 -m tipbot_fw {run,check,calibrate,bench,identify,fall-test,swing-test} ... (exit codes:
tipbot_fw.guard.exit_codes).

Order of a run: the signal handlers (before anything else), the supervisor's page if there is
one (tipbot_fw.supervisor), the configuration, gains and telemetry target (--telemetry: its
address resolved), the brick's lights and speaker (not with --quiet), the log (path checked,
room reserved), then the devices, then the session. Under the supervisor the options reach this
command line unchanged (the launcher passes its arguments on).
"""
import argparse
import os
import sys

from tipbot_fw.guard import exit_codes, heartbeat, safety
from tipbot_fw.record import logfile
from tipbot_fw.calibration import calibrate_gyro
from tipbot_fw.io.clock import MonotonicClock
from tipbot_fw.config import (SYSFS_ROOT, SYSFS_ROOT_ENV, ConfigError, check_config_against_gains,
                              default_sysfs_root, load_config)
from tipbot_fw.console import say as _say
from tipbot_fw.drive.course import CourseError, read_course
from tipbot_fw.cues import OwnerCues
from tipbot_fw.io.lights_speaker import BrickSignals
from tipbot_fw.gains import GainsError, load_gains
from tipbot_fw.session import log_refused_start, open_log, run_session
from tipbot_fw.record.telemetry import DEFAULT_EVERY, TelemetryError, TelemetrySender

CHECK_PERIOD_S = 0.005   # gyro sampling period for check/calibrate (no gains file involved)


def _positive_float(text):
    try:
        v = float(text)
    except ValueError:
        v = float('nan')
    if not v > 0.0 or v == float('inf'):
        raise argparse.ArgumentTypeError('must be a positive number of seconds, got {!r}'.format(text))
    return v


def _positive_int(text):
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError('must be a positive whole number, got {!r}'.format(text))
    return int(text)


class _ExactOptions(argparse.ArgumentParser):
    """A parser (and, being the subparsers' class, theirs) that takes options by their whole name
    only: the supervisor reads --config and --sysfs-root from the same arguments by exact name
    (tipbot_fw.supervisor._option), so an abbreviation such as --conf would give the two processes
    different robots; refused here, it is a usage error before any motor runs."""

    def __init__(self, *args, **kwargs):
        kwargs['allow_abbrev'] = False
        argparse.ArgumentParser.__init__(self, *args, **kwargs)


def _parser(argv=None):
    """The command line's parser. The experiments' and identify's own options come from their
    modules, imported only when ``argv`` (default sys.argv) names their command or asks for help:
    a run does not keep them in the brick's memory."""
    argv = sys.argv[1:] if argv is None else argv
    full = any(a in argv for a in ('fall-test', 'swing-test', 'identify', '-h', '--help'))
    p = _ExactOptions(prog='python3 -m tipbot_fw', description='tipbot firmware',
                                epilog=exit_codes.help_text(),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest='command')

    def common(sp):
        sp.add_argument('--config', metavar='FILE', help='JSON overriding fields of default_config.json')
        sp.add_argument('--sysfs-root', metavar='DIR', default=default_sysfs_root(),
                        help='root of the ev3dev sysfs tree (default ${} or {})'.format(SYSFS_ROOT_ENV, SYSFS_ROOT))

    sp = sub.add_parser('run', help='balance')
    sp.add_argument('--gains', metavar='FILE', required=True,
                    help='the gains file (JSON, made by make gains on the host: gains/physical.json; '
                    'the launcher passes the deployed gains.json)')
    sp.add_argument('--duration', metavar='S', type=_positive_float, help='stop after S seconds')
    sp.add_argument('--remote', metavar='PORT', type=_positive_int,
                    help='drive by the speed and turn commands of UDP datagrams to this port, from the host '
                         'that started the run (docs/course-format.md, "Remote"); none for 0.3 s: it comes to rest')
    sp.add_argument('--course', metavar='FILE',
                    help='drive the timed segments of this course file from the let-go cue, then stand '
                         '(docs/course-format.md); without it the robot balances where it was let go')
    sp.add_argument('--log', metavar='FILE',
                    help='run log (default tipbot-YYYYmmdd-HHMMSS.log in logs/ if the current directory '
                    'holds tipbot_fw/, else in the current directory)')
    sp.add_argument('--quiet', action='store_true',
                    help='no lights, no tones, no words on the brick\'s screen (messages stay on stderr)')
    sp.add_argument('--telemetry', metavar='HOST:PORT',
                    help='send live telemetry (UDP) there, e.g. to `python -m hostsim watch --port PORT`')
    sp.add_argument('--telemetry-every', metavar='N', type=_positive_int, default=DEFAULT_EVERY,
                    help='one datagram every N ticks (default {})'.format(DEFAULT_EVERY))
    common(sp)
    sp = sub.add_parser('check', help='devices, drivers, battery, gyro stillness; never drives motors; with --gains '
                        'and --fall-log, the pre-flight check of the experiments against the gains (tipbot_fw.preflight)')
    sp.add_argument('--gains', metavar='FILE', help='the gains file whose robot the experiments must match')
    sp.add_argument('--fall-log', metavar='LOG', help='the fall test\'s log (python3 -m tipbot_fw fall-test)')
    sp.add_argument('--swing-log', metavar='LOG', action='append', default=[],
                    help='a swing test\'s log (python3 -m tipbot_fw swing-test), once per joint')
    common(sp)
    for kind, help_text in (('fall', 'the fall test: hold the robot upright, let go when told; the joints held '
                                      '(tipbot_fw.experiments)'),
                            ('swing', 'the swing test: link 1 held upside down, one joint swings its link '
                                      '(tipbot_fw.experiments)')):
        sp = sub.add_parser(kind + '-test', help=help_text)
        if full:
            from tipbot_fw import experiments
            sp.description = experiments.__doc__.split('\n\n')[0]
            experiments.add_arguments(sp, kind)
        common(sp)
    sp = sub.add_parser('calibrate', help='measure and print the gyro bias')
    common(sp)
    sp = sub.add_parser('bench', help='timings on the robot: reads, writes, compute, loop ticks')
    sp.add_argument('--gains', metavar='FILE', required=True, help='the gains file whose period is judged')
    sp.add_argument('--ticks', metavar='N', type=_positive_int, default=2000,
                    help='ticks timed for each measure (default 2000: 10 s at 5 ms); the motors get 1 %% duties')
    common(sp)
    sp = sub.add_parser('identify', help='drive ONE motor, record its run-up and run-down for the '
                        'host\'s motor identification (python -m hostsim identify LOG)')
    if full:
        from tipbot_fw import identify
        sp.description = identify.__doc__.split('\n\n')[0]
        identify.add_arguments(sp)
    common(sp)
    return p


def _open_devices(config, sysfs_root, source):
    """-> (Ev3Devices, None), or (None, why) after saying why on one line (missing device, wrong
    driver: named by the configuration ``source`` and field; no ev3dev2)."""
    try:
        from tipbot_fw.io.ev3dev import Ev3Devices, Ev3SetupError   # late: needs python-ev3dev2, only on the robot
    except Exception as e:
        why = '{}: {}'.format(type(e).__name__, e)
    else:
        try:
            return Ev3Devices(config, sysfs_root=sysfs_root), None
        except Ev3SetupError as e:
            why = e.one_line(source)
        except Exception as e:
            why = '{}: {}'.format(type(e).__name__, ' '.join(str(e).split()))
    _say('devices: ' + why)
    return None, why


def main(argv=None, guard=None, environ=None):
    """-> exit status. ``guard``: the SignalGuard tipbot_fw.__main__ installed first thing (else
    one is installed here); ``environ``: where to look for the supervisor (os.environ)."""
    own = guard is None
    guard = safety.SignalGuard().install() if own else guard
    try:
        hbt, problem = heartbeat.attach(environ)
        guard.heartbeat = hbt
        guard.check_pending()
        return _main(argv, guard, hbt, problem)
    except (KeyboardInterrupt, safety.Terminated) as e:
        _, code, msg = safety.classify(e)
        _say('stopped before any device was touched: {} (exit {}); no log: nothing ran'.format(msg, code))
        return code
    finally:
        if own:
            guard.restore()


def _main(argv, guard, hbt, supervisor_problem):
    args = _parser(argv).parse_args(argv)
    if args.command is None:
        _parser(argv).print_help()
        return safety.EXIT_INVALID
    if supervisor_problem:
        _say('refused to start: {}; no log: nothing ran'.format(supervisor_problem))
        return safety.EXIT_INVALID
    if args.command == 'identify':   # one motor, not the robot's full set of devices
        from tipbot_fw import identify
        return identify.main_identify(args, say=_say)
    args.heartbeat = hbt
    if args.command == 'check' and args.gains and not args.fall_log:
        _say('refused to start: check --gains needs --fall-log LOG (the pre-flight check)')
        return safety.EXIT_INVALID
    try:
        notes = []
        config = load_config(args.config, notes)
        for note in notes:
            _say(note)
        gains = load_gains(args.gains) if getattr(args, 'gains', None) else None
        if gains is not None:
            check_config_against_gains(config, gains, _config_source(args))
        telemetry = _telemetry(args)
        course = _course(args, gains, config)
        remote = _remote(args, gains, config)
    except (ConfigError, GainsError, TelemetryError, CourseError) as e:
        _say('refused to start: {}'.format(e))
        return safety.EXIT_INVALID
    cues = _cues(args)      # before the log: a signal now leaves no log behind to finish
    try:
        log = None
        if args.command == 'run':
            guard.defer()       # a signal while the file is made is raised once it is whole
            try:
                log = open_log(_log_path(args), gains, config, args.duration)
            except (OSError, logfile.LogWriteError) as e:
                _say('refused to start: {}; nothing was started'.format(e.strerror or e))
                return safety.EXIT_INVALID
            try:
                guard.arm()
            except (KeyboardInterrupt, safety.Terminated) as e:
                _refused(log, gains, config, args, e, guard, cues)
                return safety.classify(e)[1]
        args.course_segments, args.remote_receiver = course, remote
        return _start(args, config, gains, log, hbt, guard, cues, telemetry)
    finally:
        cues.close()
        if remote is not None:
            remote.close()
        if telemetry is not None:
            telemetry.close()


def _start(args, config, gains, log, hbt, guard, cues, telemetry):
    """The devices, then the command; a run refused here (devices missing, a signal while they
    are set up) gets its log and its stop cue."""
    try:
        devices, why = _open_devices(config, args.sysfs_root, _config_source(args))
    except (KeyboardInterrupt, safety.Terminated) as e:   # the device layer stopped what it had set up
        if log is not None:
            _refused(log, gains, config, args, e, guard, cues)
        return safety.classify(e)[1]
    if devices is None:
        if log is not None:     # every exit of a run writes a log, once its path is good
            _refused(log, gains, config, args, safety.DevicesMissing(' '.join(why.split())), guard, cues)
        return safety.EXIT_DEVICES
    try:
        if args.command == 'run':
            guard.defer()   # until the session's guard arms: it stops the motors and finishes the log
            return _run(args, config, gains, devices, log, hbt, guard, cues, telemetry)
        return COMMANDS[args.command](args, config, gains, devices)
    finally:
        devices.close()


def _refused(log, gains, config, args, error, guard, cues):
    """A run refused before its session: the log of the header and why, then the stop cue (with
    further signals only counted, as after a session)."""
    log_refused_start(log, gains, config, args.duration, error, say=_say)
    guard.disarm()
    reason, code, _ = safety.classify(error)
    cues.stopped(reason, code)


def _course(args, gains, config):
    """The checked segments of --course (CourseError naming the file and field), or None."""
    if getattr(args, 'course', None) is None:
        return None
    # imported here: a run that stands does not keep the drive's modules in the brick's memory
    from tipbot_fw.drive.plan import drive_problem
    problem = drive_problem(gains, config)
    if problem:
        raise CourseError('{}: cannot drive: {}'.format(args.course, problem))
    return read_course(args.course, gains.kalman.reference.limits)


def _remote(args, gains, config):
    """The --remote receiver, listening before any device is touched (CourseError naming the
    problem), or None."""
    if getattr(args, 'remote', None) is None:
        return None
    from tipbot_fw.drive.plan import drive_problem
    from tipbot_fw.drive.remote import Receiver, RemoteError, allowed_host
    problem = drive_problem(gains, config)
    if args.course is not None:
        problem = '--remote and --course: one source of commands at a time'
    if problem:
        raise CourseError('--remote {}: cannot drive: {}'.format(args.remote, problem))
    try:
        return Receiver(args.remote, allowed_host(os.environ))
    except RemoteError as e:
        raise CourseError(str(e))


def _config_source(args):
    """How messages name the configuration: its file, or the defaults."""
    return args.config or 'the default configuration (tipbot_fw/default_config.json)'


def _telemetry(args):
    if getattr(args, 'telemetry', None) is None:
        return None
    return TelemetrySender(args.telemetry, args.telemetry_every)


def _cues(args):
    """The owner's cues of a run: words, and the brick's lights and tones unless --quiet."""
    if args.command != 'run':
        return OwnerCues(streams=())
    if args.quiet:
        return OwnerCues(screen=False)
    brick = BrickSignals(args.sysfs_root)
    for problem in brick.problems:
        _say('no lights or tones: ' + problem)
    return OwnerCues(brick=brick)


def _log_path(args):
    if not args.log:
        args.log = logfile.default_path('tipbot')
    return args.log


def _ir_remote(args, gains, config, devices):
    """The EV3 IR remote as the run's command source when the devices have one and no --course
    or --remote is given (tipbot_fw.drive.ir_remote), or None."""
    ir = getattr(devices, 'ir_remote', None)
    if ir is None or args.course_segments is not None or args.remote_receiver is not None:
        return None
    from tipbot_fw.drive.plan import drive_problem
    problem = drive_problem(gains, config)
    if problem:
        _say('IR remote on {}: cannot drive ({}): the robot balances where it is let go'.format(ir[0], problem))
        return None
    from tipbot_fw.drive.ir_remote import IrRemote
    _say('driving by the IR remote on {}, channel {} (red: left wheel, blue: right wheel)'.format(*ir))
    return IrRemote(devices.read_ir_remote, gains.kalman.reference.limits, 'ir:{} channel {}'.format(*ir))


def _run(args, config, gains, devices, log, hbt, guard, cues, telemetry):
    args.remote_receiver = args.remote_receiver or _ir_remote(args, gains, config, devices)
    _say('running {} ({} variant, ts {} s), log {}{}'.format(
        gains.path, gains.model_variant, gains.ts_s, log.path,
        '' if hbt.supervised else ' (no supervisor: start with the launcher ev3/tipbot, or python3 -m '
        'tipbot_fw.supervisor -- run ..., to have the motors stopped whatever ends this process)'))
    code, header = run_session(devices, gains, config, MonotonicClock(), duration_s=args.duration, log=log,
                               heartbeat=hbt, guard=guard, cues=cues, telemetry=telemetry,
                               course=args.course_segments, remote=args.remote_receiver)
    if args.remote_receiver is not None:
        r = args.remote_receiver.summary()
        _say('remote: {} commands obeyed from {}; dropped: {}'.format(
            r['obeyed'], r['host'] or 'nobody', ', '.join('{} {}'.format(v, k) for k, v in sorted(r['dropped'].items()))))
    if telemetry is not None:
        t = header['telemetry']
        _say('telemetry: {} datagrams to {} (one every {} ticks), {} not sent{}'.format(
            t['sent'], t['target'], t['every_ticks'], t['errors'],
            ': ' + t['first_error'] if t['first_error'] else ''))
    return code


def _gyro(devices, config):
    try:
        cal = calibrate_gyro(devices, MonotonicClock(), CHECK_PERIOD_S, config['gyro_calibration'])
    except safety.SafetyStop as e:
        _say(str(e))
        return None, e.exit_code
    print('gyro bias {:.3f} deg/s (rate {}..{} deg/s, angle change {} deg in {:.2f} s, {:.1f} deg of it not '
          'explained by the bias; {} samples)'.format(
              cal.gyro_bias_dps, cal.rate_min_dps, cal.rate_max_dps, cal.angle_change_deg, cal.window_s,
              cal.unexplained_angle_deg, cal.samples))
    return cal, safety.EXIT_OK


def _check(args, config, gains, devices):
    code = safety.EXIT_OK
    print('devices: ok ({})'.format(', '.join('{} {}'.format(k, v) for k, v in sorted(config['ports'].items())
                                                 if v is not None)))
    try:
        enc, gyro = devices.read_raw()
        bv = devices.read_battery_v()
    except (OSError, ValueError) as e:
        _say('read failed: {}'.format(e))
        return safety.EXIT_DEVICE_FAILURE
    print('encoders {} counts (counts_per_rot {}), gyro angle {} deg, rate {} deg/s'.format(
        list(enc), list(devices.counts_per_rot), gyro[0], gyro[1]))
    minimum = config['limits']['min_battery_v']
    if bv < minimum:
        _say('battery {:.2f} V is below limits.min_battery_v = {} V'.format(bv, minimum))
        code = safety.EXIT_REFUSED
    else:
        print('battery {:.2f} V (minimum {} V)'.format(bv, minimum))
    _, gyro_code = _gyro(devices, config)
    code = code or gyro_code
    if gains is not None:
        from tipbot_fw.preflight import run_check
        ok, _ = run_check(gains, args.fall_log, args.swing_log, say=print)
        code = code or (safety.EXIT_OK if ok else safety.EXIT_REFUSED)
    return code


def _calibrate(args, config, gains, devices):
    return _gyro(devices, config)[1]


def _bench(args, config, gains, devices):
    from tipbot_fw.bench import brick_bench   # late: a run does not keep the bench's modules
    brick_bench(devices, gains, config, args.ticks)
    return safety.EXIT_OK


def _experiment(kind):
    def command(args, config, gains, devices):
        from tipbot_fw import experiments
        return experiments.main_experiment(kind, args, config, devices, heartbeat=args.heartbeat)
    return command


# The commands that take the devices as they are ('run' has its log, heartbeat, cues: _start)
COMMANDS = {'check': _check, 'calibrate': _calibrate, 'bench': _bench, 'fall-test': _experiment('fall'),
            'swing-test': _experiment('swing')}
