"""Why a run stops, with which exit code, and signal handling that cannot skip the motor stop.

The exit codes of `python3 -m tipbot_fw` are the table of tipbot_fw.guard.exit_codes (the cli's
--help lists it); each planned stop below carries its code.
"""
import signal

from tipbot_fw.guard.exit_codes import (EXIT_CONTROLLER_DIED, EXIT_DEVICE_FAILURE, EXIT_DEVICES,  # noqa: F401
                                        EXIT_ERROR, EXIT_INTERRUPT, EXIT_INVALID, EXIT_LIMIT, EXIT_OK,
                                        EXIT_OVERRUN, EXIT_REFUSED, EXIT_TERMINATED, EXIT_WATCHDOG)


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


class Saturated(SafetyStop):
    """A motor held at its duty limit for limits.max_saturated_s: the robot no longer balances."""
    reason = 'saturated'
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


class ImplausibleBattery(SafetyStop):
    """A battery reading outside what an EV3 runs on, or a jump no battery makes."""
    reason = 'battery_implausible'
    exit_code = EXIT_DEVICE_FAILURE


class Terminated(BaseException):
    """Raised by the signal handlers (SignalGuard). A BaseException, like KeyboardInterrupt, so
    that no `except Exception` on the way can swallow it. reason: 'sigterm' (SIGTERM, SIGHUP),
    'signal' (any other termination signal), 'watchdog' (the supervisor saw a stall and stopped
    the motors), 'supervisor_gone' (the supervisor died)."""

    def __init__(self, message, reason='sigterm', exit_code=EXIT_TERMINATED):
        BaseException.__init__(self, message)
        self.reason = reason
        self.exit_code = exit_code


# Signals whose default action ends the process, that a handler can catch. Not here: SIGKILL
# and SIGSTOP (uncatchable: the supervisor covers them), SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT,
# SIGTRAP, SIGSYS (a fault inside the interpreter: a Python handler cannot run; the process ends
# and the supervisor stops the motors), SIGPIPE and SIGXFSZ (Python ignores them: a write then
# fails with EPIPE or EFBIG, which every writer handles).
_TERMINATION_NAMES = ('SIGHUP', 'SIGINT', 'SIGQUIT', 'SIGTERM', 'SIGUSR1', 'SIGUSR2', 'SIGALRM',
                      'SIGXCPU', 'SIGVTALRM', 'SIGPROF', 'SIGIO', 'SIGPWR', 'SIGSTKFLT')


def termination_signals():
    """The catchable termination signals of this platform (with the real-time ones)."""
    out = []
    for name in _TERMINATION_NAMES:
        s = getattr(signal, name, None)
        if s is not None and int(s) not in out:
            out.append(int(s))
    lo, hi = getattr(signal, 'SIGRTMIN', None), getattr(signal, 'SIGRTMAX', None)
    if lo is not None and hi is not None:
        out += [s for s in range(int(lo), int(hi) + 1) if s not in out]
    return out


def signal_name(signum):
    """SIGTERM, SIGRTMIN+3, SIGKILL, ...: a termination signal's name first (the controller's
    stops), any other's (the supervisor's view of a controller that died), else 'signal N'."""
    for name in _TERMINATION_NAMES:
        if getattr(signal, name, None) == signum:
            return name
    lo = getattr(signal, 'SIGRTMIN', None)
    if lo is not None and signum >= lo:
        return 'SIGRTMIN+{}'.format(signum - lo)
    for name in dir(signal):
        if name.startswith('SIG') and not name.startswith('SIG_') and getattr(signal, name) == signum:
            return name
    return 'signal {}'.format(signum)


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
        import traceback   # late: only a bug needs it (and its modules are the supervisor's memory)
        traceback.print_exception(type(error), error, error.__traceback__)
    return reason, code, msg


def watchdog_stop(hbt):
    """-> the Terminated ('watchdog', exit 8) that ends a run whose motors the supervisor stopped
    after a stall, or None. The controller, back from the stall, may find this before the
    supervisor's SIGTERM arrives (its own stall limit, its own overrun stop): the run still ends as
    what it was, a stall the supervisor stopped."""
    if hbt is None or hbt.stopped_by_supervisor() is None:
        return None
    return Terminated('the supervisor saw no heartbeat for {:.0f} ms (the controller stalled) and '
                      'stopped the motors'.format(1e3 * hbt.stopped_by_supervisor()), 'watchdog', EXIT_WATCHDOG)


class SignalGuard(object):
    """Every catchable termination signal -> an exception, raised at most ONCE: SIGINT ->
    KeyboardInterrupt, the others -> Terminated (the message names the signal).

    SIGHUP: a run started over ssh gets it when the connection drops; SIGQUIT is Ctrl-\\ on the
    terminal; their default actions would kill the process with the motors still running.

    ``heartbeat`` (tipbot_fw.guard.heartbeat) tells a SIGTERM from the supervisor after a stall
    ('watchdog') and the parent-death signal of a dead supervisor ('supervisor_gone') from an
    owner's SIGTERM.

    After the first signal (or disarm()), further signals are only counted: a second Ctrl-C
    cannot interrupt the motor stop and log write that the first one started.

    defer(): a signal is kept and raised by the next arm(), not where it lands: the command line
    defers while it makes the run's log file and from the devices' set-up to the session's guard,
    so a signal in those windows still ends in a log that reads (or in none), never in a file
    half made.
    """

    def __init__(self, heartbeat=None):
        self.armed = False
        self.deferring = False
        self.installed = False
        self.ignored = 0
        self.heartbeat = heartbeat
        self.deferred = 0       # the signal kept by defer(), raised by arm()
        self.raised = None      # the exception raised for the one signal that was raised
        self._previous = {}

    def exception(self, signum):
        """The exception that stands for signum."""
        hbt = self.heartbeat
        stopped = watchdog_stop(hbt)
        if stopped is not None:
            return stopped
        if hbt is not None and not hbt.supervisor_alive():
            return Terminated('the supervisor (pid {}) died: the controller stopped the motors itself'.format(
                hbt.supervisor_pid), 'supervisor_gone')
        if signum == signal.SIGINT:
            return KeyboardInterrupt()
        if signum == getattr(signal, 'SIGHUP', None):
            return Terminated('terminated by SIGHUP (the terminal or ssh connection went away)')
        if signum == signal.SIGTERM:
            return Terminated('terminated by SIGTERM')
        return Terminated('terminated by {}'.format(signal_name(signum)), 'signal')

    def _handler(self, signum, frame):
        if self.deferring:
            if not self.deferred:
                self.deferred = signum
            else:
                self.ignored += 1
            return
        if not self.armed:
            self.ignored += 1
            return
        self.armed = False
        self.raised = self.exception(signum)
        raise self.raised

    def install(self):
        try:
            for sig in termination_signals():
                self._previous[sig] = signal.signal(sig, self._handler)
        except (ValueError, OSError):
            pass    # not the main thread (Python delivers signals only there anyway), or not settable
        self.installed = True
        self.armed = True
        return self

    def check_pending(self):
        """Raise for a signal the supervisor received (and passed on) before install()."""
        signum = self.heartbeat.requested_signal() if self.heartbeat is not None else 0
        if signum and self.armed:
            self.armed = False
            self.raised = self.exception(signum)
            raise self.raised

    def defer(self):
        """Keep a signal for the next arm() (only while armed: a disarmed guard only counts)."""
        self.deferring = self.armed

    def arm(self):
        """Signals raise again; one kept while deferred raises now."""
        self.deferring = False
        self.armed = True
        signum, self.deferred = self.deferred, 0
        if signum:
            self.armed = False
            self.raised = self.exception(signum)
            raise self.raised

    def disarm(self):
        self.armed = False
        self.deferring = False

    def restore(self):
        self.armed = False
        self.deferring = False
        self.installed = False
        for sig, handler in self._previous.items():
            try:
                signal.signal(sig, signal.SIG_DFL if handler is None else handler)
            except (ValueError, OSError):
                pass
        self._previous = {}


def run_guarded(body, stop_motors, finish, say, guard=None):
    """The shutdown skeleton of everything that drives motors (tipbot_fw.session, tipbot_fw.identify).

    body() runs with the termination signals turned into exceptions (SignalGuard: ``guard``, the
    one the command line installed before touching any device, or a new one installed here and
    removed at the end). Whatever ends it (completion, a planned stop, a signal, a bug),
    stop_motors() runs first: it returns the failures as strings, each of which is said, and must
    not raise (if it does, that is said too). Then finish(reason, exit code, message) runs with
    further signals only counted, so a second Ctrl-C cannot cut the log short; its result is
    returned. Never raises unless finish does.
    """
    error = None
    guard = SignalGuard() if guard is None else guard
    own = not guard.installed
    try:
        try:
            if own:
                guard.install()
            guard.arm()
            body()
        except BaseException as e:
            # a signal inside a C extension's import (numpy's, loaded late) comes out as its ImportError
            error = guard.raised if isinstance(e, ImportError) and guard.raised is not None else e
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
        if own:
            guard.restore()
