"""One balancing run: battery check, gyro calibration, the loop, and the guaranteed shutdown.

Whatever ends the run (duration reached, fall, a signal, device failure, overruns, a stall seen
by the supervisor, a bug) the motors are stopped first, then the log is finished, then the
reason is reported. The log is open before the devices are touched, and its rows reach the
file while the robot runs (tipbot_fw.record.logfile): its header at the start, the calibration and the
encoder zeros as they are learnt, the rows in chunks, the end of the run last. The file has a
fixed size (config log_max_rows): a longer run keeps its first log_head_rows rows and its last
ones (logfile.keep_plan), and the run's last line names the ticks between them, not kept.
"""
import math
import sys
import time

import numpy as np

import tipbot_fw
from tipbot_fw.record import logfile
from tipbot_fw import side_tasks
from tipbot_fw.calibration import calibrate_gyro
from tipbot_fw.cores.core import make_core, row_layout
from tipbot_fw.cues import OwnerCues
from tipbot_fw.guard.heartbeat import NOT_SUPERVISED
from tipbot_fw.loop import ControlLoop
from tipbot_fw.console import say
from tipbot_fw.guard.plausibility import EncoderBound, check_battery
from tipbot_fw.guard.safety import EXIT_ERROR, EXIT_OK, DeviceFailure, LowBattery, outcome, run_guarded
from tipbot_fw import vocabulary


def base_header(gains, config, duration_s):
    """The log header's start: what ran, and how a reader makes the file's columns of the stored
    rows (the core's row layout)."""
    header = {
        'versions': {'python': sys.version.split()[0], 'numpy': np.__version__,
                     'tipbot_fw': tipbot_fw.__version__},
        'start_wall_time_s': time.time(),
        'start_wall_time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        'gains': {'path': gains.path, 'sha256': gains.sha256, 'schema_version': gains.schema_version,
                  'state_units_file': gains.state_units_file, 'u_max_v': gains.u_max_v,
                  'closed_loop_spectral_radius': gains.closed_loop_spectral_radius,
                  'detector_spectral_radius': gains.detector_spectral_radius,
                  'parameters_sha256': gains.parameters_sha256, 'generator': gains.generator},
        'model_variant': gains.model_variant,
        'ts_s': gains.ts_s,
        'config': config,
        'duration_s_requested': duration_s,
        'flag_bits': vocabulary.FLAG_BITS,
    }
    header.update(row_layout(gains, config).header())
    return header


def open_log(log_path, gains, config, duration_s):
    """The run's LogWriter (the rows of the core the configuration selects), with room reserved
    for its rows; LogWriteError (the path, a full disk) before anything runs."""
    keep = logfile.keep_plan(config['log_max_rows'], config['log_head_rows'], _needed_rows(gains.ts_s, duration_s))
    return logfile.open_run_log(log_path, keep, row_layout(gains, config))


class BeatingClock(object):
    """A clock whose sleeps beat the heartbeat: the calibration's samples keep the supervisor's
    watch alive before the control loop beats it every tick."""

    def __init__(self, clock, heartbeat):
        self.clock, self.heartbeat, self.now, self.k = clock, heartbeat, clock.now, 0

    def sleep_until(self, t):
        self.k += 1
        self.heartbeat.beat(self.k)
        self.clock.sleep_until(t)


def run_session(devices, gains, config, clock, log_path=None, duration_s=None,
                realtime_priority=None, say=say, cues=None, log=None, heartbeat=NOT_SUPERVISED, guard=None,
                telemetry=None, course=None, remote=None):
    """Balance until duration_s (None: until stopped). -> (exit code, log header dict).

    Never raises; devices.stop_all() is called on every exit (tipbot_fw.guard.safety.run_guarded).
    The log: ``log``, a LogWriter the caller opened (the command line opens it before the
    devices), or one opened here at log_path; None of either: no log. ``cues``
    (tipbot_fw.cues.OwnerCues by default) tells the owner to hold the robot, to let go, that it
    balances and why it stopped; ``telemetry`` (a tipbot_fw.record.telemetry.TelemetrySender or None)
    sends the ticks' rows. Both work in the loop's slack (tipbot_fw.side_tasks). ``heartbeat``: the
    supervisor's page, armed during the calibration and from the loop's first tick until the
    motors are stopped. ``guard``: the SignalGuard already installed (tipbot_fw.cli), or None.
    ``course``: the segments of tipbot_fw.drive.course (checked against the gains' limits) to drive
    from the let-go cue, or None: the robot balances where it was let go. ``remote``: a
    tipbot_fw.drive.remote.Receiver whose commands it drives by (the caller closes it), or None.
    """
    cues = OwnerCues() if cues is None else cues
    if realtime_priority is None:
        realtime_priority = config['realtime_priority']
    header = base_header(gains, config, duration_s)
    header['counts_per_rot'] = list(devices.counts_per_rot)
    header['supervised'] = heartbeat.supervised
    header['first_tick'] = 0     # a file holds a run's rows from its first tick (and a long run's last ones)
    if remote is not None:
        header['remote'] = {'host': remote.host}
    if course is not None:
        header['course'] = [{'speed_mps': v, 'yaw_rate_dps': math.degrees(w), 'duration_s': d} for v, w, d in course]
    layout = row_layout(gains, config)
    if log is None and log_path:
        try:
            log = open_log(log_path, gains, config, duration_s)
        except logfile.LogWriteError as e:
            say('no log: {}'.format(e.strerror))
    if log is not None:
        log.header(header)
    rows = logfile.LogBuffer.for_file(log, layout) if log is not None else \
        logfile.LogBuffer(min(config['log_max_rows'], _needed_rows(gains.ts_s, duration_s) or 1 << 62), layout)
    run = {}    # what body() got to build: the core and the loop

    def learnt(doc):
        header.update(doc)
        if log is not None:
            log.info(doc)

    def body():
        lim = config['limits']
        # the core first: its fixed-point format refuses a configuration before anything moves
        core = run['core'] = make_core(gains, config, devices.counts_per_rot, layout)
        follower = None
        if course is not None:      # before the calibration: nothing is watched or driven yet
            from tipbot_fw.drive.pathfollow import follow_course  # here: a run that stands keeps it out of memory
            follower = follow_course(gains, core, course)
        live = None
        if remote is not None:
            from tipbot_fw.drive.remote import live_plan, remote_side
            live = live_plan(gains, core)
        try:
            bv = devices.read_battery_v()
        except (OSError, ValueError) as e:
            raise DeviceFailure('battery read failed: {}'.format(e))
        learnt({'battery_v_start': bv})
        check_battery(bv)
        if bv < lim['min_battery_v']:
            raise LowBattery('battery at {:.2f} V is below limits.min_battery_v = {} V: charge it'.format(
                bv, lim['min_battery_v']))
        cal_config = config['gyro_calibration']
        cues.hold_still(cal_config['settle_s'] + cal_config['duration_s'])
        heartbeat.arm()
        t_start = clock.now()
        cal = calibrate_gyro(devices, BeatingClock(clock, heartbeat), gains.ts_s, cal_config)
        heartbeat.disarm()      # until the loop's first tick (ControlLoop.run): no motor driven yet
        # the session's own timing (the clock's seconds): the calibration's first and last
        # samples, the loop's first tick (at the end); a simulated hand lets go at the last sample
        run['timing'] = {'calibration_start_s': t_start, 'calibration_end_s': clock.now()}
        learnt({'calibration': cal.as_dict(), 'timing': dict(run['timing'])})
        core.set_gyro_bias(cal.gyro_bias_dps)
        rows.first_info = core.header       # the encoder zeros and the start estimate, with the first rows
        run['loop'] = ControlLoop(devices, core, clock, rows, gains.ts_s, bv,
                                  battery_period_s=config['battery_period_s'],
                                  overrun_window_s=lim['overrun_window_s'], max_lost_s=lim['max_lost_s'],
                                  max_stall_s=lim['max_stall_s'], max_saturated_s=lim['max_saturated_s'],
                                  duration_s=duration_s, realtime_priority=realtime_priority,
                                  heartbeat=heartbeat, on_scheduling=say,
                                  encoder_bound=EncoderBound(config, devices.counts_per_rot, gains.ts_s))
        cues.let_go()
        run['loop'].side = side_tasks.combine(   # after let_go: the rest of its melody plays in the loop
            cues.in_loop(run['loop'], lim['warn_battery_v']),
            telemetry.attach(rows, run['loop'].stats, core) if telemetry else None,
            remote_side(remote, live, gains.ts_s) if live is not None else None,
            follower.side() if follower is not None else None)
        run['loop'].run()

    def stop_motors():
        failures = devices.stop_all()
        heartbeat.disarm()
        return failures

    def finish(reason, code, msg):
        end = {'stop_reason': reason, 'stop_message': msg, 'exit_code': code, 'stop_wall_time_s': time.time()}
        core = run.get('core')
        if core is not None and core.x0 is not None:
            end.update(core.header())
        if 'loop' in run:
            end['loop'] = run['loop'].stats.as_dict()
            if run['loop'].stats.ticks:     # the clock at the first tick's start (the log's log_t0)
                run['timing']['loop_start_s'] = rows.t0
        if 'timing' in run:
            end['timing'] = run['timing']
        if telemetry is not None:
            end['telemetry'] = telemetry.summary()
        rows.flush()
        end['first_tick'] = rows.first_tick() if log is None else 0
        end['ticks'] = rows.count
        end['rows_not_recorded'] = rows.not_recorded()
        header.update(end)
        note = ''
        if log is not None:
            problem = log.close(end)
            if problem:
                say('log {}: {}{}'.format(log.path, problem, '' if log.lost else
                                          '; the file keeps what was written before (it reads back, marked incomplete)'))
                if code == EXIT_OK:
                    code = header['exit_code'] = EXIT_ERROR
            note = '; no log: {} was taken away'.format(log.path) if log.lost else '; log {}'.format(log.path)
            gaps = [] if log.lost else log.not_kept()
            if gaps:
                note += ' (ticks {}: not kept, the file holds the start and the last ticks: log_max_rows, ' \
                    'log_head_rows)'.format(', '.join('{}..{}'.format(a, b) for a, b in gaps))
        say('stopped: {} (exit {}, {} ticks){}'.format(msg, code, rows.count, note))
        try:
            cues.stopped(reason, code)    # after the log: its light and tone take up to a second
        except Exception as e:            # the motors are stopped, the log written: report, never raise
            say('could not show why it stopped: {!r}'.format(e))
        return code, header

    return run_guarded(body, stop_motors, finish, say, guard)


def log_refused_start(log, gains, config, duration_s, error, say=say):
    """The log of a run refused before any device was set up (error: a SafetyStop or a signal):
    the header and how it ended, in ``log`` (an open LogWriter). Never raises."""
    header = base_header(gains, config, duration_s)
    header['stop_reason'], header['exit_code'], header['stop_message'] = outcome(error)
    log.header(header)
    problem = log.close({'stop_wall_time_s': time.time(), 'first_tick': 0, 'ticks': 0})
    if problem:
        say('stopped: {} (exit {}, no ticks); the log {} could not be finished: {}'.format(
            header['stop_message'], header['exit_code'], log.path, problem))
    else:
        say('stopped: {} (exit {}, no ticks); log {}'.format(header['stop_message'], header['exit_code'], log.path))


def _needed_rows(ts_s, duration_s):
    """Rows a run of duration_s writes at most (None: until stopped)."""
    return None if duration_s is None else max(1, int(round(duration_s / ts_s)) + 1)

