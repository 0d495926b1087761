"""Why a run stops, with which exit code, and signal handling that cannot skip the motor stop.

Exit codes of `python3 -m tipbot_fw` (also in README/cli help):
  0   run reached --duration (or check/calibrate succeeded)
  1   unexpected error (a bug): motors stopped, log written, traceback printed
  2   invalid command line, config or gains: refused to start, devices not opened, no log
  3   devices missing or with the wrong driver: refused to start, motors untouched, (run) a
      log of the header only, naming them
  4   refused to start: battery below limits.min_battery_v, the gyro moved during calibration,
      or (identify) the owner did not confirm that the motor is free to turn
  5   a device read or write failed during the run
  6   fall (|th1| beyond limits.th1_rad) or a joint beyond its limit: stopped in that tick
  7   limits.max_consecutive_overruns late ticks in a row
  130 interrupted (Ctrl-C, SIGINT)
  143 terminated (SIGTERM)
"""
import signal
import traceback

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_INVALID = 2
EXIT_DEVICES = 3
EXIT_REFUSED = 4
EXIT_DEVICE_FAILURE = 5
EXIT_LIMIT = 6
EXIT_OVERRUN = 7
EXIT_INTERRUPT = 130
EXIT_TERMINATED = 143


class SafetyStop(Exception):
    """A planned stop: known reason, known exit code, one-line message."""
    reason = 'error'
    exit_code = EXIT_ERROR


class FallDetected(SafetyStop):
    reason = 'fall'
    exit_code = EXIT_LIMIT


class JointLimit(SafetyStop):
    reason = 'joint_limit'
    exit_code = EXIT_LIMIT


class DeviceFailure(SafetyStop):
    reason = 'device_failure'
    exit_code = EXIT_DEVICE_FAILURE


class OverrunLimit(SafetyStop):
    reason = 'overruns'
    exit_code = EXIT_OVERRUN


class LowBattery(SafetyStop):
    reason = 'low_battery'
    exit_code = EXIT_REFUSED


class CalibrationError(SafetyStop):
    reason = 'calibration'
    exit_code = EXIT_REFUSED


class DevicesMissing(SafetyStop):
    reason = 'devices'
    exit_code = EXIT_DEVICES


class Terminated(BaseException):
    """Raised by the SIGTERM handler. A BaseException, like KeyboardInterrupt, so that no
    `except Exception` on the way can swallow it."""
    reason = 'sigterm'
    exit_code = EXIT_TERMINATED


def classify(exc):
    """-> (reason, exit code, one-line message) for an exception that ended a run."""
    if isinstance(exc, (SafetyStop, Terminated)):
        return exc.reason, exc.exit_code, str(exc) or exc.reason
    if isinstance(exc, KeyboardInterrupt):
        return 'keyboard_interrupt', EXIT_INTERRUPT, 'interrupted'
    return 'exception', EXIT_ERROR, '{}: {}'.format(type(exc).__name__, exc)


def outcome(error):
    """-> (reason, exit code, message) of a run that ended with `error` (None: it completed).
    An unexpected error (a bug) also gets its traceback printed, for the owner to report."""
    if error is None:
        return 'completed', EXIT_OK, 'completed'
    reason, code, msg = classify(error)
    if code == EXIT_ERROR:
        traceback.print_exception(type(error), error, error.__traceback__)
    return reason, code, msg


class SignalGuard(object):
    """SIGTERM and SIGHUP -> Terminated, SIGINT -> KeyboardInterrupt, each raised at most ONCE.

    SIGHUP: a run started over ssh gets it when the connection drops; its default action
    would kill the process with the motors still running at their last duty.

    After the first signal (or disarm()), further signals are only counted: a second Ctrl-C
    cannot interrupt the motor stop and log write that the first one started.
    """

    def __init__(self):
        self.armed = False
        self.ignored = 0
        self._previous = {}

    def _handler(self, signum, frame):
        if not self.armed:
            self.ignored += 1
            return
        self.armed = False
        if signum == signal.SIGTERM:
            raise Terminated('terminated by SIGTERM')
        if signum == getattr(signal, 'SIGHUP', None):
            raise Terminated('terminated by SIGHUP (the terminal or ssh connection went away)')
        raise KeyboardInterrupt()

    def install(self):
        try:
            for sig in (signal.SIGTERM, signal.SIGINT, getattr(signal, 'SIGHUP', None)):
                if sig is not None:
                    self._previous[sig] = signal.signal(sig, self._handler)
        except ValueError:
            pass    # not the main thread: Python delivers signals only there anyway
        self.armed = True
        return self

    def disarm(self):
        self.armed = False

    def restore(self):
        self.armed = False
        for sig, handler in self._previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        self._previous = {}


def run_guarded(body, stop_motors, finish, say):
    """The shutdown skeleton of everything that drives motors (tipbot_fw.session, tipbot_fw.identify).

    body() runs with SIGTERM, SIGHUP and SIGINT turned into exceptions (SignalGuard). Whatever
    ends it (completion, a planned stop, a signal, a bug), stop_motors() runs first: it returns
    the failures as strings, each of which is said, and must not raise (if it does, that is said
    too). Then finish(reason, exit code, message) runs with further signals only counted, so a
    second Ctrl-C cannot cut the log short; its result is returned. Never raises unless finish does.
    """
    error = None
    guard = SignalGuard()
    try:
        try:
            guard.install()
            body()
        except BaseException as e:
            error = e
        finally:
            guard.disarm()
    finally:
        try:
            failures = stop_motors() or ()
        except Exception as e:   # stopping must not raise; if it does, say so loudly
            failures = ['stopping the motors failed: {!r}'.format(e)]
        for failure in failures:
            say(failure)
    try:
        return finish(*outcome(error))
    finally:
        guard.restore()
