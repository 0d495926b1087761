"""Time on the brick: each sysfs access, the tick's own Python and the scheduler cost time.

On the EV3 a Python tacho read or duty write takes 0.3-0.45 ms, mostly in the kernel; a
sensor attribute costs less; interrupts take about 14 % of the CPU and a kernel worker
another 20 % with the gyro plugged in (../shared/ev3-hardware.md). In the lock-step
simulation time only moves when someone moves it, so here:

- :class:`TimedIO` stands between the firmware's device layer (tipbot_fw.io.ev3dev, which takes
  an ``io`` with the API of :mod:`os`) and the fake EV3's :class:`CountingIO`. Every pread
  and pwrite advances the virtual clock by a sampled access time; the value a read returns
  is the world's at the middle of its access, and a duty reaches the motor at the middle of
  its write (in run-direct "a new duty reaches the PWM during the write() itself"). So the
  five reads sample the robot at five moments and the duties land one by one.
- The tick's own Python (signal chain, law, log row) is charged after its reads, before the
  next write or clock reading (:class:`BrickClock`), once the control loop runs.
- :meth:`AccessTimes.wake_delay` makes wake-ups late: with some probability a kernel thread
  still holds the CPU, and now and then a multi-tick stall (an SD card write, a burst of
  kernel work) holds everything.
- Every duration is stretched by 1 / (1 - cpu_steal): the interrupts' share of the CPU.
- The brick's lights and speaker (tipbot_fw.io.lights_speaker: a LED's ``brightness``, a tone event on
  the sound input device), written in the loop's slack after the duties, cost what a sensor
  access does: a small attribute write, mostly the Python call (3,800 and 7,300 ARMv5
  instructions on the virtual brick, docs/benchmarks.md), little kernel work. So they take brick time
  like the rest, and a side task that runs long makes the next wake-up late.

A gyro mode write blocks as long as the fake EV3 says (FakeEV3.write_cost), whether or not
the accesses are timed, and fails with ETIMEDOUT on a stuck sensor.
"""
import math
import os

from tipbot_fw.io.clock import VirtualClock

_BLOCK = 4096

# what a file is, by the end of its path
KIND_POSITION, KIND_TACHO_WRITE, KIND_SENSOR, KIND_FEEDBACK, KIND_OTHER = range(5)


class _Uniforms(object):
    """U(0, 1) numbers drawn in blocks (a numpy call per access would cost more than the
    access's whole simulation)."""

    def __init__(self, rng):
        self.rng = rng
        self.buf = []

    def __call__(self):
        if not self.buf:
            self.buf = self.rng.random(_BLOCK).tolist()
        return self.buf.pop()


class AccessTimes(object):
    """Durations (s) sampled from a scenario's Brick (hostsim.sim.scenario) with ``rng``."""

    def __init__(self, brick, rng):
        self.u = _Uniforms(rng)
        self.stretch = 1.0 / (1.0 - brick.cpu_steal)
        self.ranges = {KIND_POSITION: brick.tacho_access_s, KIND_TACHO_WRITE: brick.tacho_access_s,
                       KIND_SENSOR: brick.sensor_access_s, KIND_FEEDBACK: brick.sensor_access_s}
        self.compute_range = brick.compute_s
        self.late_p = brick.late_wake_probability
        self.late_range = brick.late_wake_s
        self.stall_rate = brick.stall_rate_hz
        self.stall_range = brick.stall_s
        self.next_stall = self._exponential(0.0)
        self.stalls = []           # (start, duration) of each stall so far
        # the one stall of a given length (margins' single-stall row), at a random phase of the
        # loop's period: 0-10 ms after its time (drawn after the first stall, whatever its use)
        self.once = None
        if brick.single_stall_s > 0:
            self.once = (brick.single_stall_at_s + 0.01 * self.u(), brick.single_stall_s)

    def _between(self, lo_hi):
        lo, hi = lo_hi
        return lo + (hi - lo) * self.u()

    def _exponential(self, after):
        if self.stall_rate > 0 and self.stall_range[1] > 0:
            return after - math.log(1.0 - self.u()) / self.stall_rate
        return math.inf

    def access(self, kind):
        r = self.ranges.get(kind)
        return 0.0 if r is None else self._between(r) * self.stretch

    def compute(self):
        return self._between(self.compute_range) * self.stretch

    def wake_delay(self, t_wake):
        """How late a wake-up due at t_wake comes: a kernel thread's remaining time, and every
        stall that started before it."""
        late = 0.0
        if self.late_p > 0 and self.u() < self.late_p:
            late = self._between(self.late_range)
        if self.once is not None and self.once[0] <= t_wake + late:
            start, d = self.once
            self.once = None
            self.stalls.append((start, d))
            late = max(late, start + d - t_wake)
        while self.next_stall <= t_wake + late:
            d = self._between(self.stall_range)
            self.stalls.append((self.next_stall, d))
            late = max(late, self.next_stall + d - t_wake)
            self.next_stall = self._exponential(self.next_stall + d)
        return late


class BrickClock(VirtualClock):
    """The virtual clock with the tick's compute time charged lazily: TimedIO sets
    ``pending`` after a tick's reads, and the next clock reading or write pays it."""

    def __init__(self, start=0.0, on_sleep=None):
        VirtualClock.__init__(self, start, on_sleep)
        self.pending = 0.0

    def charge(self):
        if self.pending:
            self.t += self.pending
            self.pending = 0.0

    def now(self):
        if self.pending:
            self.charge()
        return self.t

    def sleep_until(self, t):
        self.charge()
        VirtualClock.sleep_until(self, t)


def kind_of(relpath):
    """What an attribute is (KIND_*), by its name."""
    name = relpath.rsplit('/', 1)[-1]
    if name == 'position':
        return KIND_POSITION
    if name == 'duty_cycle_sp' or name == 'command':
        return KIND_TACHO_WRITE
    if name in ('bin_data', 'voltage_now') or name.startswith('value'):
        return KIND_SENSOR
    if name in ('brightness', 'trigger', 'platform-sound-event'):
        return KIND_FEEDBACK
    return KIND_OTHER


class TimedIO(object):
    """``os``-like open/pread/pwrite/write/close over a fake EV3's CountingIO (module docstring).

    ``world`` provides sample(relpath, t) (publish that attribute's value as of t) and
    wrote(relpath, t) (apply a client's write at t); ``times`` is an AccessTimes, or None to
    leave the accesses free (only the fake's blocking writes then cost time).
    ``end_of_reads``: the relpath whose read ends a tick's reads (the gyro's bin_data);
    ``world.loop_running()`` says whether to charge the tick's compute time after it.
    """

    def __init__(self, inner, fake, clock, world, times=None, end_of_reads=None):
        self.inner = inner
        self.fake = fake
        self.clock = clock
        self.world = world
        self.times = times
        self.end_of_reads = end_of_reads
        self.kinds = {}

    def open(self, path, flags, mode=0o777):
        fd = self.inner.open(path, flags, mode)
        rel = self.inner.open_fds[fd]
        self.kinds[fd] = (rel, kind_of(rel))
        return fd

    def close(self, fd):
        self.kinds.pop(fd, None)
        self.inner.close(fd)

    def pread(self, fd, n, offset):
        if self.times is not None:
            rel, kind = self.kinds[fd]
            clock = self.clock
            t0 = clock.now()
            d = self.times.access(kind)
            self.world.sample(rel, t0 + 0.5 * d)
            clock.t = t0 + d
            if rel == self.end_of_reads and self.world.loop_running():
                clock.pending = self.times.compute()
        return self.inner.pread(fd, n, offset)

    def pwrite(self, fd, data, offset):
        return self._write(fd, data, self.inner.pwrite, (fd, data, offset))

    def write(self, fd, data):
        return self._write(fd, data, self.inner.write, (fd, data))

    def _write(self, fd, data, op, args):
        rel, kind = self.kinds[fd]
        clock = self.clock
        t0 = clock.now()
        block, err = self.fake.write_cost(rel, data)
        d = block + (0.0 if self.times is None else self.times.access(kind))
        if err is not None:
            clock.t = t0 + d
            raise OSError(err, os.strerror(err), rel)
        out = op(*args)
        if self.times is not None:
            self.world.wrote(rel, t0 + (0.5 * d if kind == KIND_TACHO_WRITE else d))
        clock.t = t0 + d
        return out
