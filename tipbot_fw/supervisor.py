"""The guard that outlives the controller: ``python3 -m tipbot_fw.supervisor [OPTIONS] -- ARGS``.

A small process (standard library only: no numpy, it starts in a fraction of the controller's
time) that starts the controller ``python3 -m tipbot_fw ARGS`` as its child and stops every
motor of the configured ports itself, directly through sysfs (``duty_cycle_sp`` 0, then
``command`` ``stop``), when

* the controller ends, however it ends (SIGKILL, a segfault, the OOM killer, an exit): the
  controller holds the write end of a pipe, so its end is an end of file the supervisor's
  ``select`` sees at once;
* the controller's heartbeat stands still while it is armed (tipbot_fw.guard.heartbeat: the control
  loop stores its tick index in a shared page every tick, no system call) for longer than the
  configuration's ``limits.max_stall_s`` (150 ms): the longest single stall the robot is
  designed to ride out (docs/architecture.md), or for longer than ``--timeout-ms`` (25 ms, 5 periods)
  with a held duty at the saturation the controller published in the page (a controller that
  froze while fighting a fall, or a runaway). A frozen controller's H-bridges keep its last
  duties: a delayed version of the law, which a balancing robot rides out for a while, where
  stopping its motors would be a fall; the controller, back from the stall, predicts through
  the periods it missed (tipbot_fw.cores.kalman: skip). Past that hold the supervisor stops the
  motors, marks the page and sends SIGTERM and SIGCONT: the
  controller, if it ever runs again, finds its motors in ``stop`` (a motor whose command is
  ``stop`` ignores ``duty_cycle_sp``, the only attribute the controller writes during a run),
  stops the run with the reason ``watchdog`` (exit 8) and writes its log. A controller that has
  not ended ``--grace-s`` after that is killed.

It checks every ``--poll-ms`` (10 ms), so a death or a stall's end of hold is acted on within a
poll and the stop writes (0.45 ms each on the brick): within 15 ms, inside the 50 ms asked.
With ``realtime_priority`` in the configuration it runs SCHED_FIFO one level above the
controller, so a controller that spins at its own real-time priority cannot starve it.

Termination signals the supervisor receives (SIGINT from Ctrl-C, SIGTERM, SIGHUP, ...) go on to
the controller, which stops its motors and writes its log; the supervisor waits for it. The
controller is started with these signals ignored until it has installed its own handlers, which
then look at the request the supervisor left in the page, so a Ctrl-C during the controller's
start-up is neither lost nor a traceback. If the supervisor dies, the kernel sends the
controller SIGTERM (prctl PR_SET_PDEATHSIG; and the controller checks its parent about once a
second): it stops its motors itself.

A signal to the whole process group (SIGKILL or SIGSTOP of both processes at once, as a shell's
kill -- -PGID or Ctrl-Z does) would leave no one to stop the motors: so the supervisor forks a
guard into a session of its own (start_guard), which watches the same pipe and page and stops
the motors when the controller ends, or when it stands still past its hold while the
supervisor stands still too.

Exit status: the controller's (``python3 -m tipbot_fw --help``); 128 + N when it ended on a
signal N this supervisor passed on to it (one that came while its first was ending it); or 9
when the controller died without exiting (killed by any other signal): the motors were stopped
here, its log keeps the rows it wrote, and (unless the run was --quiet) the brick's lights,
speaker and screen show it as the controller shows its own stops (tipbot_fw.cues, loaded only
then). ``--bench-polls N`` runs N polls without sleeping, for tools/tick-cost.

The options reach the controller as they are: ``-- run --gains ... --quiet --telemetry HOST:PORT``.
The supervisor reads two of them itself: ``--config`` (the motor ports) and ``--sysfs-root``
(default: $TIPBOT_SYSFS_ROOT, then /sys/class, as the controller's).
"""
try:
    import signal
except KeyboardInterrupt:       # Ctrl-C in the interpreter's first milliseconds: nothing started
    if __name__ != '__main__':
        raise
    import sys
    sys.stderr.write('tipbot: supervisor: interrupted while starting: nothing was started\n')
    sys.exit(130)

# Before the imports below: a Ctrl-C while this module loads is noted, not a traceback, and
# supervise() then starts nothing.
_EARLY = []


def _note_early(signum, frame):
    _EARLY.append(signum)


if __name__ == '__main__':
    for _s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT):
        signal.signal(_s, _note_early)

import os  # noqa: E402
import select  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from tipbot_fw.guard import heartbeat as hb  # noqa: E402
from tipbot_fw.config import ConfigError, default_sysfs_root, load_config  # noqa: E402
from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.guard.realtime import ask_fifo, refused  # noqa: E402
from tipbot_fw.guard.safety import EXIT_CONTROLLER_DIED, EXIT_INVALID, signal_name, termination_signals  # noqa: E402

TIMEOUT_S = 0.025
POLL_S = 0.010
GRACE_S = 5.0
PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def say(msg, who='supervisor'):
    try:
        sys.stderr.write('tipbot: {}: {}\n'.format(who, msg))
        sys.stderr.flush()
    except (OSError, ValueError):     # a vanished console must not stop the supervisor
        pass


def _option(argv, name):
    """The value of ``name VALUE`` or ``name=VALUE`` in the controller's arguments, or None; the
    last one when it is given twice, as the controller's argparse takes it (the launcher puts the
    deployed ``--config`` first, an owner's ``./tipbot --config other.json`` after it)."""
    value = None
    for i, a in enumerate(argv):
        if a == name and i + 1 < len(argv):
            value = argv[i + 1]
        elif a.startswith(name + '='):
            value = a[len(name) + 1:]
    return value


def motor_ports(config):
    return [config['ports'][r] for r in MOTOR_ROLES]


class MotorStopper(object):
    """duty_cycle_sp 0 and command stop on the tacho motors of ``ports``, through file
    descriptors opened at start (a stop is then 2 writes per motor, no lookup); a motor whose
    descriptors fail is looked up again and retried once. held_duties() reads what the motors
    are driven at (only while the controller stands still)."""

    def __init__(self, sysfs_root, ports):
        self.root = sysfs_root
        self.ports = list(ports)
        self.fds = {}
        self.missing = []
        self._open()

    def _dirs(self):
        """{port: device directory} of the tacho motors present."""
        base = os.path.join(self.root, 'tacho-motor')
        found = {}
        try:
            names = os.listdir(base)
        except OSError:
            return found
        for name in names:
            try:
                with open(os.path.join(base, name, 'address'), 'rb') as f:
                    port = f.read(64).split(b'\n', 1)[0].strip().decode('ascii', 'replace')
            except OSError:
                continue
            found[port.split(':')[-1]] = os.path.join(base, name)
        return found

    def _open(self):
        self._close()
        dirs = self._dirs()
        self.missing = []
        for port in self.ports:
            if port not in dirs:
                self.missing.append(port)
                continue
            try:
                self.fds[port] = (os.open(os.path.join(dirs[port], 'duty_cycle_sp'), os.O_RDWR),
                                  os.open(os.path.join(dirs[port], 'command'), os.O_WRONLY))
            except OSError:
                self.missing.append(port)

    def _close(self):
        for fds in self.fds.values():
            for fd in fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.fds = {}

    def _write(self):
        failed = []
        for port, (duty, command) in sorted(self.fds.items()):
            try:
                os.pwrite(duty, b'0\n', 0)
                os.pwrite(command, b'stop\n', 0)
            except OSError as e:
                failed.append('port {}: {}'.format(port, e))
        return failed

    def held_duties(self):
        """The duties the motors hold (percent; a motor that cannot be read is left out)."""
        out = []
        for port, (duty, _) in sorted(self.fds.items()):
            try:
                out.append(int(os.pread(duty, 16, 0).split(b'\n', 1)[0]))
            except (OSError, ValueError):
                pass
        return out

    def stop(self):
        """Stop them. Never raises. -> the problems, as strings (none: all stopped)."""
        failed = self._write()
        if failed or self.missing:
            self._open()
            failed = self._write()
        return failed + ['port {}: no tacho motor found'.format(p) for p in self.missing]


class Watch(object):
    """The supervisor's view of one controller: its pipe, its page, its stall timer."""

    def __init__(self, words, pipe_r, timeout_s=TIMEOUT_S, clock=time.monotonic, count_polls=True):
        self.words = words
        self.count_polls = count_polls      # the supervisor's polls, which the guard watches
        self.pipe_r = pipe_r
        self.timeout_s = timeout_s
        self.clock = clock
        self.last_beat = words[hb.BEAT]
        self.last_change = clock()
        self.was_armed = False

    def poll(self, wait_s):
        """Wait up to wait_s for the controller's end. -> 'ended', 'stalled' (the time the beat
        stood still, s) or None. One select and a few loads: its cost is what `make bench`
        measures per poll."""
        ready = select.select([self.pipe_r], [], [], wait_s)[0]
        if ready:
            return 'ended', 0.0
        words = self.words
        if self.count_polls:
            words[hb.POLLS] = (words[hb.POLLS] + 1) & 0xffffffff
        t = self.clock()
        beat = words[hb.BEAT]
        armed = words[hb.STATE] == hb.ARMED
        if beat != self.last_beat or not self.was_armed:
            self.last_beat = beat
            self.last_change = t
        self.was_armed = armed
        if armed and t - self.last_change > self.timeout_s:
            return 'stalled', t - self.last_change
        return None


class Child(object):
    """The controller's process, started as subprocess.Popen would start it (fork, then exec with
    ``pass_fds`` kept open and ``ignored`` signals ignored; an exec failure is this constructor's
    OSError), without importing subprocess: its modules are about 2 MB of this process's memory
    on the brick, and the guard's copy of them more."""

    def __init__(self, argv, env, pass_fds, ignored):
        err_r, err_w = os.pipe()            # closed by a successful exec (O_CLOEXEC)
        self.pid = os.fork()
        if self.pid == 0:
            try:
                for sig in ignored:
                    signal.signal(sig, signal.SIG_IGN)
                for fd in pass_fds:
                    os.set_inheritable(fd, True)
                os.execvpe(argv[0], argv, env)
            except OSError as e:
                os.write(err_w, str(e.errno or 0).encode('ascii'))
            finally:
                os._exit(127)
        os.close(err_w)
        failed = os.read(err_r, 16)
        os.close(err_r)
        self.returncode = None
        if failed:
            os.waitpid(self.pid, 0)
            errno = int(failed)
            raise OSError(errno, os.strerror(errno), argv[0])

    def _ended(self, status):
        self.returncode = -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)
        return self.returncode

    def poll(self):
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self._ended(status)
        return self.returncode

    def wait(self):
        if self.returncode is None:
            while True:
                try:
                    return self._ended(os.waitpid(self.pid, 0)[1])
                except InterruptedError:
                    continue
        return self.returncode

    def kill(self):
        try:
            os.kill(self.pid, signal.SIGKILL)
        except OSError:
            pass


def _realtime(priority):
    if priority <= 0:
        return
    info, _ = ask_fifo(min(99, priority + 1))
    # not permitted: the controller's start line says so, for both, with what to do
    if not info['granted'] and not refused(info):
        say('no real-time priority ({}): a controller spinning at its own could starve this guard'.format(
            info['error']))


def supervise(argv, timeout_s=TIMEOUT_S, poll_s=POLL_S, grace_s=GRACE_S, python=None):
    """Run the controller with ``argv`` (python3 -m tipbot_fw ARGV) under watch. -> exit status."""
    signals = termination_signals()
    received = list(_EARLY)
    child = {}

    def on_signal(signum, frame):
        received.append(signum)
        if 'words' in child:
            child['words'][hb.REQUEST] = signum
        if 'proc' in child:
            try:
                os.kill(child['proc'].pid, signum)
            except OSError:
                pass

    for s in signals:
        signal.signal(s, on_signal)
    try:
        config = load_config(_option(argv, '--config'))
    except ConfigError as e:
        say('refused to start: {}'.format(e))
        return EXIT_INVALID
    sysfs_root = _option(argv, '--sysfs-root') or default_sysfs_root()
    stopper = MotorStopper(sysfs_root, motor_ports(config))
    hold_s = config['limits']['max_stall_s']
    page_fd, page, words = hb.create_page()
    child['words'] = words
    pipe_r, pipe_w = os.pipe()
    env = dict(os.environ)
    env[hb.ENV] = '{}:{}:{}'.format(page_fd, pipe_w, os.getpid())
    env['PYTHONPATH'] = os.pathsep.join([PACKAGE_PARENT] + [p for p in [env.get('PYTHONPATH')] if p])
    for s in received:       # a signal before the controller exists: nothing to start
        say('{} before the controller started: not started'.format(signal_name(s)))
        return 128 + s
    try:
        proc = Child([python or sys.executable, '-m', 'tipbot_fw'] + list(argv), env, (page_fd, pipe_w), signals)
    except OSError as e:
        say('cannot start the controller: {}'.format(e))
        return EXIT_INVALID
    child['proc'] = proc
    os.close(pipe_w)
    os.close(page_fd)
    if received:
        on_signal(received[-1], None)
    _realtime(config['realtime_priority'])
    guard_pid = start_guard(words, pipe_r, stopper, hold_s, timeout_s, poll_s, proc.pid)
    watch = Watch(words, pipe_r, timeout_s)
    kill_at = None
    while True:
        event = watch.poll(poll_s)
        if event is None:
            if kill_at is not None and time.monotonic() > kill_at:
                _report(stopper.stop(), 'before killing the controller')
                say('the controller did not end {:.0f} s after the stop: killing it'.format(grace_s))
                proc.kill()
                kill_at = None
            continue
        kind, stood_s = event
        if kind == 'ended':
            t_end = time.monotonic()
            problems = stopper.stop()
            stop_ms = (time.monotonic() - t_end) * 1e3
            code = proc.wait()
            _reap(guard_pid)
            _report(problems, 'after the controller ended')
            if code < 0 and -code in received:
                # the signal passed on, delivered while the controller had no handler for it: at
                # the very end of its exit (the interpreter's finalization restores the default
                # actions), after a first one had already ended it: that signal's own status
                say('the controller ended on the {} passed on to it: motors stopped here'.format(signal_name(-code)))
                return 128 - code
            if code < 0:
                say('the controller was killed by {}: motors stopped here {:.1f} ms after its end; its log keeps '
                    'the rows it wrote'.format(signal_name(-code), stop_ms))
                # a stalled controller killed after its grace was stopped for the stall
                show_stop(argv, sysfs_root, 'watchdog' if words[hb.STOPPED] else 'controller_died',
                          EXIT_CONTROLLER_DIED)
                return EXIT_CONTROLLER_DIED
            return code
        if kind == 'stalled' and kill_at is None:
            if words[hb.STOPPED]:
                # the guard stopped it while this process stood still too (a SIGSTOP of both)
                say('the guard stopped the motors of the stalled controller')
                kill_at = time.monotonic() + grace_s
                continue
            why = _past_hold(stood_s, hold_s, stopper, words[hb.RAIL])
            if why is None:
                continue        # a frozen controller's last duties: held while the robot can be saved
            problems = stopper.stop()
            words[hb.MISSED_US] = min(int(stood_s * 1e6), 0xffffffff)
            words[hb.STOPPED] = 1
            _report(problems, 'of a stalled controller')
            say('the controller missed its heartbeat for {:.0f} ms{}: motors stopped; stopping it'.format(
                stood_s * 1e3, why))
            for s in (signal.SIGTERM, signal.SIGCONT):
                try:
                    os.kill(proc.pid, s)
                except OSError:
                    pass
            kill_at = time.monotonic() + grace_s


def _past_hold(stood_s, hold_s, stopper, rail):
    """Why a controller whose beat stood still stood_s must lose its motors now, or None while
    its held duties may still save the robot: beyond hold_s (limits.max_stall_s), or a held
    duty at the controller's saturation limit `rail` (0: not published yet, the 100 % of the
    driver)."""
    if stood_s > hold_s:
        return ', longer than limits.max_stall_s = {} s'.format(hold_s)
    held = stopper.held_duties()
    rail = rail or 100
    if any(abs(d) >= rail for d in held):
        return ' with a motor held at its saturation ({} %)'.format(rail)
    return None


def start_guard(words, pipe_r, stopper, hold_s, timeout_s, poll_s, controller_pid):
    """Fork the guard: a copy of this process (its pages shared until written: a few hundred kB of
    its own) in a session of its own, so that no signal to the run's process group (a SIGKILL or a
    SIGSTOP of the supervisor and the controller at once, Ctrl-Z) reaches it. It watches the same
    pipe and page: the controller's end stops the motors at once, as here; a frozen controller
    past its hold has its motors stopped, but only while this supervisor stands still too (its
    poll counter does not move for two polls: otherwise this process acts, and only one of them
    signals the controller). It ends with the controller (the pipe's end of file). -> its pid, or
    None if it could not be started (the run goes on with this supervisor alone, said)."""
    try:
        pid = os.fork()
    except OSError as e:
        say('no guard outside the process group ({}): a signal to the whole group is not covered'.format(e))
        return None
    if pid:
        return pid
    code = 0
    try:
        os.setsid()
        for s in (signal.SIGINT, signal.SIGHUP, signal.SIGQUIT, signal.SIGTSTP):
            signal.signal(s, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        guard(words, pipe_r, stopper, hold_s, timeout_s, poll_s, controller_pid)
    except BaseException:    # never a traceback from a second copy, never its exit status
        code = 1
    finally:
        os._exit(code)


def guard(words, pipe_r, stopper, hold_s, timeout_s, poll_s, controller_pid, clock=time.monotonic):
    """The guard's loop (start_guard); returns when the controller has ended and its motors are
    stopped."""
    watch = Watch(words, pipe_r, timeout_s, clock=clock, count_polls=False)
    polls, polls_seen = words[hb.POLLS], clock()
    while True:
        event = watch.poll(poll_s)
        if event is None:
            continue
        kind, stood_s = event
        if kind == 'ended':
            problems = stopper.stop()
            if words[hb.STATE] == hb.ARMED and not words[hb.STOPPED]:
                _report(problems, 'after the controller and the supervisor ended', who='guard')
            return
        t = clock()
        if words[hb.POLLS] != polls:
            polls, polls_seen = words[hb.POLLS], t
            continue                        # the supervisor is there: its call
        if words[hb.STOPPED] or t - polls_seen < 2 * poll_s:
            continue
        why = _past_hold(stood_s, hold_s, stopper, words[hb.RAIL])
        if why is None:
            continue
        problems = stopper.stop()
        words[hb.MISSED_US] = min(int(stood_s * 1e6), 0xffffffff)
        words[hb.STOPPED] = 1
        _report(problems, 'of a stalled controller', who='guard')
        say('the controller and the supervisor stood still, the controller for {:.0f} ms{}: motors stopped'.format(
            stood_s * 1e3, why), who='guard')
        for s in (signal.SIGTERM, signal.SIGCONT):
            try:
                os.kill(controller_pid, s)
            except OSError:
                pass


def _reap(pid, wait_s=0.2):
    """Collect the guard (it ends within a poll of the controller); one that does not (stopped
    itself) is left to init rather than waited for."""
    if pid is None:
        return
    t_end = time.monotonic() + wait_s
    while True:
        try:
            done, _ = os.waitpid(pid, os.WNOHANG)
        except OSError:
            return
        if done or time.monotonic() > t_end:
            return
        time.sleep(0.005)


def show_stop(argv, sysfs_root, reason, code):
    """A stop the controller could not show, on the brick's lights, speaker and screen (a second,
    after the motors are stopped), unless the run was --quiet. Never raises."""
    if argv[:1] != ['run'] or '--quiet' in argv:
        return
    try:
        from tipbot_fw.cues import OwnerCues
        from tipbot_fw.io.lights_speaker import BrickSignals
        cues = OwnerCues(brick=BrickSignals(sysfs_root))
        try:
            cues.stopped(reason, code)
        finally:
            cues.close()
    except Exception as e:      # the motors are stopped: a light is not worth a traceback
        say('could not show the stop on the brick: {!r}'.format(e))


def _report(problems, when, who='supervisor'):
    for p in problems:
        say('stopping the motors {}: {}'.format(when, p), who)



def bench(polls):
    """polls polls of a Watch on an idle pipe and a beating page, without sleeping."""
    fd, page, words = hb.create_page()
    r, w = os.pipe()
    watch = Watch(words, r)
    words[hb.STATE] = hb.ARMED
    for k in range(polls):
        words[hb.BEAT] = k
        watch.poll(0.0)
    return 0


USAGE = ('usage: python3 -m tipbot_fw.supervisor [--timeout-ms MS] [--poll-ms MS] [--grace-s S] -- ARGS\n'
         '       python3 -m tipbot_fw.supervisor --bench-polls N')


def main(argv=None):
    args = list(sys.argv[1:] if argv is None else argv)
    opts = {'--timeout-ms': TIMEOUT_S * 1e3, '--poll-ms': POLL_S * 1e3, '--grace-s': GRACE_S}
    while args and args[0] != '--':
        if args[0] == '--bench-polls' and len(args) > 1 and args[1].isdigit():
            return bench(int(args[1]))
        if args[0] in opts and len(args) > 1:
            try:
                opts[args[0]] = float(args[1])
            except ValueError:
                pass
            else:
                args = args[2:]
                continue
        sys.stderr.write(USAGE + '\n')
        return EXIT_INVALID
    if not args or not 1.0 <= opts['--timeout-ms'] <= 1000.0 or not 1.0 <= opts['--poll-ms'] <= 100.0:
        sys.stderr.write(USAGE + '\n')
        return EXIT_INVALID
    return supervise(args[1:], opts['--timeout-ms'] * 1e-3, opts['--poll-ms'] * 1e-3, opts['--grace-s'])


if __name__ == '__main__':
    sys.exit(main())
