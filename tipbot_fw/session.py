"""One balancing run: battery check, gyro calibration, the loop, and the guaranteed shutdown.

Whatever ends the run (duration reached, fall, SIGTERM, Ctrl-C, device failure, overruns, a bug)
the motors are stopped first, then the log is written, then the reason is reported.
"""
import sys
import time

import numpy as np

import tipbot_fw
from tipbot_fw import logfile
from tipbot_fw.calibration import calibrate_gyro
from tipbot_fw.core import make_core
from tipbot_fw.loop import ControlLoop
from tipbot_fw.console import say
from tipbot_fw.safety import EXIT_ERROR, EXIT_OK, DeviceFailure, LowBattery, run_guarded


def base_header(gains, config, duration_s):
    return {
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
        'flag_bits': logfile.FLAG_BITS,
    }


def run_session(devices, gains, config, clock, log_path=None, duration_s=None,
                realtime_priority=None, say=say):
    """Balance until duration_s (None: until stopped). -> (exit code, log header dict).

    Never raises; devices.stop_all() is called on every exit (tipbot_fw.safety.run_guarded).
    The log (if log_path) is written on every exit too, with the rows recorded so far.
    """
    if realtime_priority is None:
        realtime_priority = config['realtime_priority']
    header = base_header(gains, config, duration_s)
    header['counts_per_rot'] = list(devices.counts_per_rot)
    header['estimator'] = config['estimator']
    run = {}    # what body() got to build: the core, its log buffer and the loop

    def body():
        core = run['core'] = make_core(gains, config, devices.counts_per_rot)
        log = run['log'] = logfile.LogBuffer(_log_rows(config, gains.ts_s, duration_s), core.rows)
        lim = config['limits']
        try:
            bv = devices.read_battery_v()
        except (OSError, ValueError) as e:
            raise DeviceFailure('battery read failed: {}'.format(e))
        header['battery_v_start'] = bv
        if bv < lim['min_battery_v']:
            raise LowBattery('battery at {:.2f} V is below limits.min_battery_v = {} V: charge it'.format(
                bv, lim['min_battery_v']))
        cal = calibrate_gyro(devices, clock, gains.ts_s, config['gyro_calibration'])
        header['calibration'] = cal.as_dict()
        core.set_gyro_bias(cal.gyro_bias_dps)
        run['loop'] = ControlLoop(devices, core, clock, log, gains.ts_s, bv,
                                  battery_period_s=config['battery_period_s'],
                                  max_consecutive_overruns=lim['max_consecutive_overruns'],
                                  duration_s=duration_s, realtime_priority=realtime_priority)
        run['loop'].run()

    def finish(reason, code, msg):
        header['stop_reason'] = reason
        header['stop_message'] = msg
        header['exit_code'] = code
        header['stop_wall_time_s'] = time.time()
        core = run.get('core')
        log = run.get('log')
        if core is not None and core.x0 is not None:
            header.update(core.header())
        if 'loop' in run:
            header['loop'] = run['loop'].stats.as_dict()
        header['first_tick'] = log.first_tick() if log else 0
        header['ticks'] = log.count if log else 0
        if log_path:
            try:
                if log is None:     # stopped before its core existed: the header alone
                    logfile.write_log(log_path, header, np.zeros((0, 0)), columns=[])
                else:
                    logfile.write_log(log_path, header, log.file_blocks(), log.kept(), columns=core.rows.columns)
            except Exception as e:   # the motors are stopped: report, never raise
                say('could not write the log {}: {!r}'.format(log_path, e))
                if code == EXIT_OK:
                    code = header['exit_code'] = EXIT_ERROR
        say('stopped: {} (exit {}, {} ticks)'.format(msg, code, header['ticks']))
        return code, header

    return run_guarded(body, devices.stop_all, finish, say)


def _log_rows(config, ts_s, duration_s):
    cap = config['log_max_rows']
    if duration_s is not None:
        cap = min(cap, int(round(duration_s / ts_s)) + 1)
    return max(1, cap)

