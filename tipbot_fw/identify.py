"""Motor identification on the brick (the paper's Section 4): drive ONE motor, record its
run-up and its run-down, write an identify log.

    python3 -m tipbot_fw identify --port outA [--duty 100] [--seconds 2] [--yes] [--log FILE]

What it does, in order:

1. finds the tacho motor on ``--port`` (python-ev3dev2, as tipbot_fw.io.ev3dev does; any motor
   driver: large, medium or NXT), opens ``position``, ``duty_cycle_sp``, ``command`` and the
   battery's ``voltage_now`` once, and sets duty 0, ``stop_action`` coast, polarity normal;
2. reads the battery and refuses to go on below ``limits.min_battery_v`` (config);
3. says what it will do and asks for confirmation (skipped with ``--yes``; with no terminal
   and no ``--yes`` it refuses): the shaft must turn freely, i.e. the wheel lifted off the
   ground, or the joint's link taken off;
4. records the motor standing still (``--still-seconds``), then writes the duty and
   ``run-direct`` (t = 0 of the log), records for ``--seconds``, then ``stop`` with stop
   action coast (open circuit: no back-EMF braking) and duty 0, and records the run-down
   until the shaft has not moved for ``--still-seconds`` or ``--rundown-seconds`` have passed;
5. stops the motor (duty 0 + stop) and writes the log (docs/log-format.md, "Identify logs").

Recording: ``position`` is read with ``os.pread`` in a tight loop, as fast as the brick
manages (``--period-ms`` > 0 limits the rate), each read timed with the clock. Reads that
only repeat the previous count are not stored, except at most every ``keepalive_s``; each
stored row carries the time of the read before it (which still saw the previous row's
count), so the rows say as much as every read would: a count changed somewhere between
``prev_read_s`` and ``time_s``. The battery is re-read every ``battery_period_s`` (and at the
start of each phase): the voltage applied is duty / 100 x battery voltage.

Safety as in the balance session (tipbot_fw.session): SIGTERM, SIGHUP and Ctrl-C are turned
into exceptions by tipbot_fw.guard.safety.SignalGuard, and whatever ends the run, the motor is
stopped first (``stop``), then the log is written with what was recorded. Exit codes are the
CLI's (tipbot_fw.guard.safety): 0 done, 1 bug, 2 invalid arguments or config, 3 no motor on the
port, 4 refused (low battery, not confirmed), 5 a read or write failed, 130 Ctrl-C, 143
SIGTERM/SIGHUP.

The host fits the log: ``python -m hostsim identify LOG`` (hostsim/logs/identify.py).

Python 3.5 + the standard library (python-ev3dev2 at start-up only).
"""
import argparse
import array
import os
import sys
import time

import numpy as np

import tipbot_fw
from tipbot_fw.io import ev3dev
from tipbot_fw.record import logfile
from tipbot_fw.io.clock import MonotonicClock
from tipbot_fw.config import ConfigError, load_config
from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.console import say
from tipbot_fw.guard.plausibility import check_battery
from tipbot_fw.guard.safety import (EXIT_DEVICES, EXIT_ERROR, EXIT_INTERRUPT, EXIT_INVALID, EXIT_OK,
                              EXIT_REFUSED, DeviceFailure, LowBattery, SafetyStop, run_guarded)

KIND = 'identify'
IDENTIFY_VERSION = 1

# Body columns of an identify log (docs/log-format.md, "Identify logs").
COLUMNS = (('time_s', 's'),        # time of this read, from the drive command (run-direct)
           ('prev_read_s', 's'),   # time of the read before, which saw the previous row's count
           ('position', 'count'),  # raw position as read (polarity normal, no reset)
           ('phase', ''),          # 0 standing still, 1 driven at `duty`, 2 coasting
           ('duty', '%'),          # duty applied in this phase
           ('battery_v', 'V'))     # last battery reading
COLUMN_NAMES = tuple(c[0] for c in COLUMNS)
N_COLUMNS = len(COLUMNS)
PHASE_STILL, PHASE_DRIVE, PHASE_COAST = 0, 1, 2
PHASE_NAMES = {PHASE_STILL: 'still', PHASE_DRIVE: 'drive', PHASE_COAST: 'coast'}

DEFAULTS = {
    'duty': 100,
    'seconds': 2.0,            # drive time: several time constants (EV3 motors: 0.03-0.15 s)
    'rundown_seconds': 4.0,    # longest run-down recorded
    'still_seconds': 0.3,      # standstill recorded before the drive; run-down ends this long still
    'period_s': 0.0,           # 0: read as fast as possible
    'keepalive_s': 0.01,       # a row at least this often even when the count does not change
    'battery_period_s': 0.05,
}

_READ_BYTES = 32


class SingleMotor(ev3dev.SysfsDevices):
    """Raw access to one tacho motor and the battery: found with python-ev3dev2 (through
    tipbot_fw.io.ev3dev's survey), then file descriptors opened once, ``pread``/``pwrite`` at 0.

    ``io``: open/pread/pwrite/close with the signatures of :mod:`os` (the default); tests pass
    hostsim's fake EV3 CountingIO. Ev3SetupError if there is no motor on the port or it cannot
    be set up; the motor is left stopped then.
    """

    def __init__(self, port, sysfs_root='/sys/class', io=os):
        ev3dev.SysfsDevices.__init__(self, io)
        self.port = ev3dev.short_port(port)
        self.pread = self._pread
        self.position_fd = self._duty_fd = self._cmd_fd = -1
        self.path, self.driver, self.counts_per_rot = find_motor(self.port, sysfs_root)
        try:
            self._open(sysfs_root)
            self._set_up()
        except BaseException:
            self.close()
            raise

    def _open(self, sysfs_root):
        def open_attr(name, flags):
            return self._open_attr(self.port, name, flags, self.path + '/' + name)

        self.position_fd = open_attr('position', os.O_RDONLY)
        self._duty_fd = open_attr('duty_cycle_sp', os.O_WRONLY)
        self._cmd_fd = open_attr('command', os.O_WRONLY)
        self._open_battery(sysfs_root)
        self._opened()

    def _set_up(self):
        self._setup_write(self.port, 'duty_cycle_sp', self._duty_fd, '0')
        self._write_once(self.port, self.path, 'stop_action', 'coast')
        self._write_once(self.port, self.path, 'polarity', 'normal')

    def _write(self, name, fd, data):
        try:
            self._pwrite(fd, data, 0)
        except OSError as e:
            raise ev3dev.Ev3WriteError(self.port, name, 'writing', e)

    def run_direct(self, duty):
        """Duty (int percent) then ``run-direct``: the motor starts during the second write."""
        self._write('duty_cycle_sp', self._duty_fd, ('%d\n' % duty).encode('ascii'))
        self._write('command', self._cmd_fd, b'run-direct\n')

    def coast(self):
        """``stop`` (stop_action coast: open circuit), then duty 0."""
        self._write('command', self._cmd_fd, b'stop\n')
        self._write('duty_cycle_sp', self._duty_fd, b'0\n')

    def stop_all(self):
        """``stop`` and duty 0. Never raises; -> the failures as strings."""
        return self._stop_writes([(self.port, 'command', self._cmd_fd, b'stop\n'),
                                  (self.port, 'duty_cycle_sp', self._duty_fd, b'0\n')], 'stop')

    def _forget_fds(self):
        self.position_fd = self._duty_fd = self._cmd_fd = -1


def find_motor(port, sysfs_root='/sys/class'):
    """-> (device dir, driver_name, count_per_rot) of the tacho motor on ``port``.
    Ev3SetupError if there is none (the message lists the ports that have one)."""
    with ev3dev.under_root(sysfs_root) as ev3dev2:
        try:
            found = ev3dev.survey(ev3dev2, 'tacho-motor', 'motor*')
        except OSError as e:
            raise ev3dev.Ev3SetupError(['{}: cannot list tacho motors: {}'.format(sysfs_root, e)])
        if port not in found:
            raise ev3dev.Ev3SetupError(['port {}: no motor found (tacho motors on: {})'.format(
                port, ', '.join(sorted(found)) or 'none')])
        path, driver = found[port]
        return path, driver, ev3dev.count_per_rot(ev3dev2, path)


class Recorder(object):
    """Reads the motor's position in a tight loop and keeps the rows of the log (absolute
    clock times; made relative to the drive command when written)."""

    def __init__(self, motor, clock, period_s=0.0, keepalive_s=DEFAULTS['keepalive_s'],
                 battery_period_s=DEFAULTS['battery_period_s']):
        self.motor = motor
        self.clock = clock
        self.period_s = float(period_s)
        self.keepalive_s = float(keepalive_s)
        self.battery_period_s = float(battery_period_s)
        self.rows = array.array('d')
        self.reads = {}           # phase -> reads
        self.spans = {}           # phase -> (first read time, last read time)
        self.max_read_gap_s = 0.0
        self.battery_reads = []   # (time, volts)
        self.last_count = None
        self.t_prev = None
        self.battery_v = None

    def nrows(self):
        return len(self.rows) // N_COLUMNS

    def read_battery(self):
        v = self.motor.read_battery_v()
        self.battery_v = v
        self.battery_reads.append((self.clock.now(), v))
        return v

    def record(self, phase, duty, t_end, still_s=None):
        """Record until the clock reaches t_end or, with still_s, until the count has not
        changed for still_s. -> 'time' or 'still'. DeviceFailure if a read fails."""
        now = self.clock.now
        sleep_until = self.clock.sleep_until
        pread = self.motor.pread
        fd = self.motor.position_fd
        extend = self.rows.extend
        period = self.period_s
        keep = self.keepalive_s
        last_c = self.last_count
        t_prev = self.t_prev
        gap = self.max_read_gap_s
        try:
            bv = self.read_battery()
        except (OSError, ValueError) as e:
            raise DeviceFailure('battery read failed: {}'.format(e))
        t_batt = now() + self.battery_period_s
        t_row = None
        t_moved = now()
        n = 0
        t_first = None
        ended = 'time'
        while True:
            t = now()
            try:
                c = int(pread(fd, _READ_BYTES, 0))
            except (OSError, ValueError) as e:
                raise DeviceFailure('port {}: reading position failed: {}'.format(self.motor.port, e))
            n += 1
            if t_prev is None:
                t_prev = t
            elif t - t_prev > gap:
                gap = t - t_prev
            done = t >= t_end
            if c != last_c:
                t_moved = t
            elif still_s is not None and t - t_moved >= still_s:
                done = True
                ended = 'still'
            if t_row is None or done or c != last_c or t - t_row >= keep:
                extend((t, t_prev, c, phase, duty, bv))
                t_row = t
                if t_first is None:
                    t_first = t
            last_c = c
            t_prev = t
            if done:
                break
            if t >= t_batt:
                try:
                    bv = self.read_battery()
                except (OSError, ValueError) as e:
                    raise DeviceFailure('battery read failed: {}'.format(e))
                t_batt = t + self.battery_period_s
            if period > 0.0:
                sleep_until(t + period)
        self.last_count = last_c
        self.t_prev = t_prev
        self.max_read_gap_s = gap
        self.reads[phase] = self.reads.get(phase, 0) + n
        self.spans[phase] = (t_first, t_prev)
        return ended

    def relative_rows(self, t0):
        """The rows with time_s and prev_read_s relative to t0 (array of doubles, row-major)."""
        out = array.array('d', self.rows)
        for i in range(0, len(out), N_COLUMNS):
            out[i] -= t0
            out[i + 1] -= t0
        return out


def write_identify_log(path, header, rows):
    """Write an identify log: the run log's container (docs/log-format.md) with COLUMNS as its
    columns and ``kind: "identify"`` in its header. rows: a flat sequence of doubles, row-major.
    tipbot_fw.record.logfile.read_log reads it."""
    header = dict(header)
    header['kind'] = KIND
    body = np.frombuffer(array.array('d', rows).tobytes(), dtype='=f8')
    if body.size % N_COLUMNS:
        raise ValueError('identify rows: {} values is not a whole number of {}-column rows'.format(
            body.size, N_COLUMNS))
    logfile.write_log(path, header, body.reshape(-1, N_COLUMNS), columns=COLUMNS)


def run_identify(motor, clock, duty=DEFAULTS['duty'], seconds=DEFAULTS['seconds'],
                 rundown_seconds=DEFAULTS['rundown_seconds'], still_seconds=DEFAULTS['still_seconds'],
                 period_s=DEFAULTS['period_s'], keepalive_s=DEFAULTS['keepalive_s'],
                 battery_period_s=DEFAULTS['battery_period_s'], min_battery_v=None,
                 log_path=None, header_extra=None, say=say):
    """Record the standstill, the drive at ``duty`` for ``seconds`` and the coasting run-down.
    -> (exit code, log header). Never raises; the motor is stopped on every exit, then the
    log (if log_path) is written with what was recorded."""
    header = {
        'kind': KIND,
        'identify_version': IDENTIFY_VERSION,
        'versions': {'python': sys.version.split()[0], 'tipbot_fw': tipbot_fw.__version__},
        'start_wall_time_s': time.time(),
        'start_wall_time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        'port': motor.port, 'driver': motor.driver, 'counts_per_rot': motor.counts_per_rot,
        'duty': int(duty), 'seconds_requested': seconds, 'rundown_seconds_max': rundown_seconds,
        'still_seconds': still_seconds, 'period_s_requested': period_s, 'keepalive_s': keepalive_s,
        'battery_period_s': battery_period_s, 'min_battery_v': min_battery_v,
        'stop_action': 'coast', 'polarity': 'normal',
        'phases': dict((str(k), v) for k, v in PHASE_NAMES.items()),
        'drive_command_s': None, 'coast_command_s': None, 'rundown_end': None,
    }
    header.update(header_extra or {})
    rec = Recorder(motor, clock, period_s, keepalive_s, battery_period_s)
    times = {}    # t0: the drive command's time, the origin of the log's times

    def body():
        try:
            bv = rec.read_battery()
        except (OSError, ValueError) as e:
            raise DeviceFailure('battery read failed: {}'.format(e))
        header['battery_v_start'] = bv
        check_battery(bv)
        if min_battery_v is not None and bv < min_battery_v:
            raise LowBattery('battery at {:.2f} V is below limits.min_battery_v = {} V: charge it'.format(
                bv, min_battery_v))
        rec.record(PHASE_STILL, 0, clock.now() + still_seconds)
        t0 = times['t0'] = clock.now()
        try:
            motor.run_direct(duty)
        except OSError as e:
            raise DeviceFailure(str(e))
        t1 = clock.now()
        header['drive_command_s'] = [0.0, t1 - t0]
        rec.record(PHASE_DRIVE, duty, t0 + seconds)
        tc = clock.now()
        try:
            motor.coast()
        except OSError as e:
            raise DeviceFailure(str(e))
        header['coast_command_s'] = [tc - t0, clock.now() - t0]
        header['rundown_end'] = rec.record(PHASE_COAST, 0, tc + rundown_seconds, still_seconds)

    def finish(reason, code, msg):
        header.update(stop_reason=reason, stop_message=msg, exit_code=code,
                      stop_wall_time_s=time.time())
        header['reads'] = dict((PHASE_NAMES[p], n) for p, n in rec.reads.items())
        header['read_period_s'] = dict(
            (PHASE_NAMES[p], (rec.spans[p][1] - rec.spans[p][0]) / max(n - 1, 1))
            for p, n in rec.reads.items() if rec.spans[p][0] is not None)
        header['max_read_gap_s'] = rec.max_read_gap_s
        header['rows'] = rec.nrows()
        if rec.battery_reads:
            header['battery_v_end'] = rec.battery_reads[-1][1]
        # never driven: times from the first read
        t0 = times.get('t0', rec.rows[0] if len(rec.rows) else 0.0)
        written = False
        if log_path and rec.nrows():
            try:
                write_identify_log(log_path, header, rec.relative_rows(t0))
                written = True
            except Exception as e:   # the motor is stopped: report, never raise
                say('could not write the log {}: {!r}'.format(log_path, e))
                if code == EXIT_OK:
                    code = header['exit_code'] = EXIT_ERROR
        say('stopped: {} (exit {}); {}'.format(msg, code, _summary(header, rec, log_path if written else None)))
        return code, header

    return run_guarded(body, motor.stop_all, finish, say)


def _summary(header, rec, log_path):
    parts = []
    reads = header['reads']
    drive = reads.get('drive')
    if drive:
        parts.append('{} reads while driven (one per {:.1f} us, longest gap {:.2f} ms)'.format(
            drive, 1e6 * header['read_period_s'].get('drive', 0.0), 1e3 * header['max_read_gap_s']))
    counts = [rec.rows[i + 2] for i in range(0, len(rec.rows), N_COLUMNS)
              if rec.rows[i + 3] == PHASE_DRIVE]
    if counts:
        moved = abs(counts[-1] - counts[0])
        parts.append('the shaft turned {:.0f} counts while driven{}'.format(
            moved, ' - STALLED? it hardly moved' if moved < 20 else ''))
    parts.append('log {}'.format(log_path) if log_path else 'no log written')
    return ', '.join(parts)


# ---------------------------------------------------------------------------- command line
def _duty(text):
    try:
        v = int(text)
    except ValueError:
        v = 0
    if not (-100 <= v <= 100) or v == 0:
        raise argparse.ArgumentTypeError('must be a nonzero integer percent in [-100, 100], got {!r}'.format(text))
    return v


def _seconds(text):
    try:
        v = float(text)
    except ValueError:
        v = float('nan')
    if not 0.0 < v <= 60.0:
        raise argparse.ArgumentTypeError('must be a number of seconds in (0, 60], got {!r}'.format(text))
    return v


def _period_ms(text):
    try:
        v = float(text)
    except ValueError:
        v = float('nan')
    if not 0.0 <= v <= 100.0:
        raise argparse.ArgumentTypeError('must be a number of milliseconds in [0, 100], got {!r}'.format(text))
    return v


def add_arguments(sp):
    """The identify subcommand's options (tipbot_fw.cli adds --config, --sysfs-root)."""
    sp.add_argument('--port', required=True, metavar='PORT', help='motor port, e.g. outA')
    sp.add_argument('--duty', type=_duty, default=DEFAULTS['duty'],
                    help='duty cycle in percent, sign = direction (default 100: full power)')
    sp.add_argument('--seconds', type=_seconds, default=DEFAULTS['seconds'],
                    help='drive time (default {}; long enough to reach a steady speed)'.format(DEFAULTS['seconds']))
    sp.add_argument('--rundown-seconds', type=_seconds, default=DEFAULTS['rundown_seconds'],
                    help='longest coasting run-down recorded (default {})'.format(DEFAULTS['rundown_seconds']))
    sp.add_argument('--still-seconds', type=_seconds, default=DEFAULTS['still_seconds'],
                    help='standstill recorded before the drive; the run-down ends after the shaft has '
                         'not moved this long (default {})'.format(DEFAULTS['still_seconds']))
    sp.add_argument('--period-ms', type=_period_ms, default=1e3 * DEFAULTS['period_s'],
                    help='shortest time between two position reads (default 0: as fast as possible)')
    sp.add_argument('--yes', action='store_true', help='do not ask for confirmation')
    sp.add_argument('--log', metavar='FILE',
                    help='identify log (default identify-PORT-YYYYmmdd-HHMMSS.log in logs/ if the current '
                    'directory holds tipbot_fw/, else in the current directory)')


def _role_of(config, port):
    for role in MOTOR_ROLES:
        if ev3dev.short_port(config['ports'][role]) == port:
            return role
    return None


def _confirm(motor, args, battery_v, stdin, say):
    """True if the user typed yes (or --yes); False after saying why not."""
    what = ('port {}: {}. It will run at duty {} % (about {:.1f} V) for {} s, then coast for up to {} s.'
            .format(motor.port, motor.driver, args.duty, abs(args.duty) / 100.0 * battery_v,
                    args.seconds, args.rundown_seconds))
    free = ('The shaft must turn freely: lift the wheel off the ground; for a joint motor, take its '
            'link off (or unplug the motor from the robot).')
    if args.yes:
        say(what)
        return True
    if stdin is None or not stdin.isatty():
        say('refused: no terminal to confirm on and no --yes. {} {} Then run again with --yes.'.format(what, free))
        return False
    sys.stderr.write('{}\n{}\nType yes to start: '.format(what, free))
    sys.stderr.flush()
    answer = stdin.readline().strip().lower()
    if answer not in ('y', 'yes'):
        say('not confirmed ({!r}): the motor was not driven'.format(answer))
        return False
    return True


def main_identify(args, say=say, stdin=None, clock=None, io=os):
    """The identify subcommand (tipbot_fw.cli). -> exit code."""
    stdin = sys.stdin if stdin is None else stdin
    try:
        config = load_config(args.config)
    except ConfigError as e:
        say('refused to start: {}'.format(e))
        return EXIT_INVALID
    try:
        motor = SingleMotor(args.port, sysfs_root=args.sysfs_root, io=io)
    except Exception as e:
        say('devices: {}: {}'.format(type(e).__name__, e))
        return EXIT_DEVICES
    try:
        try:
            bv = motor.read_battery_v()
        except OSError as e:
            say('battery read failed: {}'.format(e))
            return DeviceFailure.exit_code
        minimum = config['limits']['min_battery_v']
        if bv < minimum:
            say('battery {:.2f} V is below limits.min_battery_v = {} V: charge it'.format(bv, minimum))
            return EXIT_REFUSED
        try:
            if not _confirm(motor, args, bv, stdin, say):
                return EXIT_REFUSED
        except KeyboardInterrupt:
            say('interrupted: the motor was not driven')
            return EXIT_INTERRUPT
        log_path = args.log or logfile.default_path('identify-' + motor.port)
        role = _role_of(config, motor.port)
        extra = {'role': role, 'sysfs_path': motor.path,
                 'expected_driver': config['drivers'].get(role) if role else None}
        code, _ = run_identify(motor, clock or MonotonicClock(), duty=args.duty, seconds=args.seconds,
                               rundown_seconds=args.rundown_seconds, still_seconds=args.still_seconds,
                               period_s=args.period_ms * 1e-3, min_battery_v=minimum,
                               log_path=log_path, header_extra=extra, say=say)
        return code
    except SafetyStop as e:   # not expected here (run_identify never raises); for safety
        say(str(e))
        return e.exit_code
    finally:
        motor.close()
