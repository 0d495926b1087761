"""The exit codes of `python3 -m tipbot_fw`, of its supervisor and of the launcher: the one table
that the firmware's --help, the safety module, the launcher, `tools/deploy run` (`make run`'s
messages) and docs/safety.md (tests/test_docs.py compares it) all read.

Standard library only and no imports: tools/deploy loads it on a host without numpy, the
supervisor and the launcher before anything else.
"""

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_INVALID = 2
EXIT_DEVICES = 3
EXIT_REFUSED = 4
EXIT_DEVICE_FAILURE = 5
EXIT_LIMIT = 6
EXIT_OVERRUN = 7
EXIT_WATCHDOG = 8
EXIT_CONTROLLER_DIED = 9
EXIT_INTERRUPT = 130
EXIT_TERMINATED = 143

# (code, what it means, whether a run that ends with it has a log)
TABLE = (
    (EXIT_OK, 'the run reached --duration (or check/calibrate succeeded)', True),
    (EXIT_ERROR, 'an unexpected error (a bug): motors stopped, log written, traceback printed', True),
    (EXIT_INVALID, 'invalid command line, configuration or gains, or a log path that cannot be written (or no '
                   'room for the log): refused to start, devices not opened, no log (the message says why)', False),
    (EXIT_DEVICES, 'devices missing or with the wrong driver: refused to start, motors untouched, (run) a log '
                   'of the header only, naming them', True),
    (EXIT_REFUSED, 'refused to start: battery below limits.min_battery_v, the gyro moved during calibration, '
                   'or (identify) the owner did not confirm that the motor is free to turn', True),
    (EXIT_DEVICE_FAILURE, 'a device read or write failed during the run, or a reading no hardware can give (a '
                          'gyro rate beyond +-440 deg/s, an encoder jump faster than any motor turns, a battery '
                          'voltage outside what an EV3 can run on or jumping implausibly)', True),
    (EXIT_LIMIT, 'a fall (|th1| beyond limits.th1_rad) or a joint beyond its limit: stopped in that tick; or a '
                 'motor held at its saturation for limits.max_saturated_s (the robot fallen while a sensor '
                 'stopped, running away, blocked or held)', True),
    (EXIT_OVERRUN, 'the loop fell behind: more than limits.max_lost_s lost to late ticks (periods skipped, '
                   'lateness) within limits.overrun_window_s', True),
    (EXIT_WATCHDOG, 'the controller stalled: its supervisor saw no heartbeat, stopped the motors and stopped it',
     True),
    (EXIT_CONTROLLER_DIED, '(supervisor) the controller died without exiting (SIGKILL, a crash, out of memory): '
                           'the supervisor stopped the motors; the log keeps the rows written before', True),
    (EXIT_INTERRUPT, 'interrupted (Ctrl-C, SIGINT)', True),
    (EXIT_TERMINATED, 'terminated by a signal (SIGTERM, SIGHUP, SIGQUIT, SIGUSR1, ...: the log names it), or '
                      'the supervisor died and the controller stopped its motors itself', True),
)
MEANINGS = dict((code, meaning) for code, meaning, _ in TABLE)
# the exits of a run after which its log is there to fetch
WITH_LOG = tuple(code for code, _, log in TABLE if log)


def help_text(width=96):
    """The table as --help shows it: the code, then its meaning wrapped under it."""
    lines = ['exit codes:']
    for code, meaning, _ in TABLE:
        words, line = meaning.split(), '  {:<4}'.format(code)
        for w in words:
            if len(line) + 1 + len(w) > width and line.strip() != str(code):
                lines.append(line)
                line = '      ' + w
            else:
                line += ('' if line.endswith(' ') else ' ') + w
        lines.append(line)
    return '\n'.join(lines)


def markdown_table():
    """The table as docs/safety.md shows it."""
    rows = ['| code | meaning |', '|---|---|']
    rows += ['| {} | {} |'.format(code, meaning.replace('|', '\\|')) for code, meaning, _ in TABLE]
    return '\n'.join(rows)
