"""Real-process fault injection: the firmware under its supervisor (tipbot_fw.supervisor) against a
fake EV3 sysfs tree (hostsim.world.fake_ev3) that nothing polls: the motors' state is read from
the files the firmware and the supervisor write, as the kernel driver would apply it.

Used by tests/test_supervisor.py and tools/fault-tally. A run is held at a joint angle that
makes the controller drive its motors; then a fault is injected, and the time until every
motor's duty_cycle_sp reads 0 and its command reads stop is measured by polling the files.
"""
import os
import signal
import subprocess
import sys
import time

from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw.config import SYSFS_ROOT_ENV
from tipbot_fw.record.logfile import read_log

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PORTS = ('outA', 'outB', 'outC', 'outD')
QUICK = {'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.02, 'duration_s': 0.05}}


def first_line(path):
    with open(path, 'rb') as f:
        return f.read(64).split(b'\n', 1)[0].strip().decode('ascii', 'replace')


class Robot(object):
    """A fake EV3 in ``root`` and the firmware started on it under the supervisor."""

    def __init__(self, root, gains, config_path, log_path, supervised=True, extra=(), env=None, root_by_env=False):
        """root_by_env: the fake tree named by TIPBOT_SYSFS_ROOT (as the loopback brick does), not
        by --sysfs-root."""
        self.fake = FakeEV3(root, battery_v=8.0)
        self.fake.set_readings((0, 0, 0, 0))
        self.log_path = log_path
        env = dict(env or {})
        if root_by_env:
            env[SYSFS_ROOT_ENV] = self.fake.sysfs_root
        args = ['run', '--gains', gains, '--config', config_path, '--log', log_path] + \
            ([] if root_by_env else ['--sysfs-root', self.fake.sysfs_root]) + list(extra)
        cmd = [sys.executable, '-m', 'tipbot_fw.supervisor', '--'] + args if supervised else \
            [sys.executable, '-m', 'tipbot_fw'] + args
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env=dict(os.environ, **(env or {})), start_new_session=True)
        self.supervised = supervised

    def paths(self, name):
        return [self.fake.attribute_path(p, name) for p in PORTS]

    def duties(self):
        return [first_line(p) for p in self.paths('duty_cycle_sp')]

    def commands(self):
        return [first_line(p) for p in self.paths('command')]

    def stopped(self):
        return all(d == '0' for d in self.duties()) and all(c == 'stop' for c in self.commands())

    def driving(self):
        return all(c == 'run-direct' for c in self.commands()) and any(d not in ('0', '') for d in self.duties())

    def controller_pid(self):
        if not self.supervised:
            return self.proc.pid
        try:
            with open('/proc/{0}/task/{0}/children'.format(self.proc.pid)) as f:
                kids = f.read().split()
        except OSError:
            return None
        for kid in kids:        # the controller, not the guard (a fork of the supervisor)
            try:
                with open('/proc/{}/cmdline'.format(kid), 'rb') as f:
                    if b'\0-m\0tipbot_fw\0' in f.read():
                        return int(kid)
            except OSError:
                pass
        return None

    def wait_driving(self, timeout_s=20.0):
        """Turn joint 2 slowly to and fro (1 count per 10 ms, between 0 and 28 counts, 0.5 rad), so
        that it is off the start pose the loop takes as its zero whenever the loop starts (after
        the calibration and the start cues) and the controller drives; -> True once the motors
        are driven."""
        t_end = time.monotonic() + timeout_s
        t0 = None
        while time.monotonic() < t_end:
            if self.proc.poll() is not None:
                return False
            if t0 is None and all(c == 'run-direct' for c in self.commands()):
                t0 = time.monotonic()
            if t0 is not None:
                n = int((time.monotonic() - t0) * 100) % 56
                self.fake.set_readings((0, 0, n if n <= 28 else 56 - n, 0))
            if self.driving():
                time.sleep(0.4)         # a few chunks of log rows written
                return self.driving()
            time.sleep(0.002)
        return False

    def time_to_stop(self, timeout_s=2.0):
        """Seconds from now until every motor reads duty 0 and command stop (None: not within timeout_s)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            if self.stopped():
                return time.monotonic() - t0
            time.sleep(0.0002)
        return None

    def finish(self, timeout_s=20.0):
        """-> (exit status, stdout, stderr) once the process tree ended."""
        try:
            out, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            out, err = self.proc.communicate()
        return self.proc.returncode, out.decode('utf-8', 'replace'), err.decode('utf-8', 'replace')

    def log(self):
        return read_log(self.log_path)

    def close(self):
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except OSError:
                pass
            self.proc.wait()
        self.fake.close()


def inject(robot, fault):
    """Inject ``fault`` into a driving robot -> seconds to all motors stopped (None: never).
    Faults: 'kill-controller', 'kill-supervisor', 'stop-controller', 'kill-group' and 'stop-group'
    (SIGKILL, SIGSTOP to the run's whole process group), 'stop-both' (SIGSTOP to the supervisor,
    then to the controller), or a signal name sent to the controller ('SIGQUIT', ...)."""
    pid = robot.controller_pid()
    if fault == 'kill-controller':
        os.kill(pid, signal.SIGKILL)
    elif fault == 'kill-supervisor':
        os.kill(robot.proc.pid, signal.SIGKILL)
    elif fault == 'stop-controller':
        os.kill(pid, signal.SIGSTOP)
    elif fault == 'kill-group':
        os.killpg(robot.proc.pid, signal.SIGKILL)
    elif fault == 'stop-group':
        os.killpg(robot.proc.pid, signal.SIGSTOP)
    elif fault == 'stop-both':
        os.kill(robot.proc.pid, signal.SIGSTOP)
        os.kill(pid, signal.SIGSTOP)
    else:
        os.kill(pid, getattr(signal, fault) if fault.startswith('SIG') and hasattr(signal, fault)
                else int(fault))
    t = robot.time_to_stop()
    if fault == 'kill-supervisor':
        # the controller, an orphan now, ends by itself: wait for it to write its log
        t_end = time.monotonic() + 10
        while time.monotonic() < t_end and os.path.exists('/proc/{}'.format(pid)) and \
                open('/proc/{}/stat'.format(pid)).read().split()[2] != 'Z':
            time.sleep(0.01)
    return t
