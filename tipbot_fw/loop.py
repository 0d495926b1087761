"""The fixed-period control loop: timing, the tick pipeline, housekeeping, overrun policy.

Tick pipeline: read raw -> plausibility of the readings -> heartbeat -> the core (estimate,
control, saturation, duty, log row: tipbot_fw.cores.core) -> write duties -> the row's time columns.
A control tick does exactly one read_raw (5 sysfs reads) and one write_duties (at most 4 writes).

Timing: tick k is released at t0 + k * period, the deadline advanced by exactly one period each
tick (no drift). A tick whose work ends after the next release is an overrun: the next tick
starts at once; releases missed entirely are skipped (whole periods, the grid is kept) and
counted. The cores always assume the nominal period (the model is discrete at ts_s).

The overrun stop: whether the loop is falling behind, not whether a few ticks were late. The time
lost within the last limits.overrun_window_s (the whole periods skipped there x period, plus the
lateness of the tick just ended) is the time the controller's model did not see; the loop stops
(OverrunLimit, exit 7) when it exceeds limits.max_lost_s: 40 ms within 0.3 s by default, a hold
of the order of the gains' delay margins, the window twice the closed loop's slowest balancing
mode (docs/architecture.md derives both). A burst of slightly late ticks, or one stall of a few
periods, loses less; a tick that always takes longer than the period skips a period every few
ticks and is stopped within a window. The bookkeeping runs only in a late tick: an on-time tick
pays one comparison, as before.

Each tick stores its index in the heartbeat page the supervisor watches (one store, no system
call: tipbot_fw.guard.heartbeat), and compares the readings with what the hardware can report
(tipbot_fw.guard.plausibility: a gyro rate beyond +-440 deg/s, an encoder jump beyond the motor's
reach at the nominal period; only when that cheap test fails is the exact one, with the time
since the previous read, made). That check is also what keeps the wheels' count changes within
the core's max_count_step (the Kalman core's fixed-point range): the core does not check again.

Between ticks, after the tick's writes and its overrun bookkeeping, in this order: the
saturation stop and the log's rows, written to the file in whole chunks (logfile.CHUNK_ROWS, on the grid of chunks: the slots
of the file's ring of a long run's last rows; no fsync in the loop); the battery
(about once a second: its plausibility, and whether the supervisor is still there); the side
task (tipbot_fw.side_tasks: lights, tones, telemetry). Each runs in the first tick, from the one it
is due in, that leaves at least SLACK_S (SLACK_FRACTION of a shorter period) before the next
release, so that none of them makes a tick late. What cannot wait any longer runs at once: the
rows when the ring in memory is about to be overwritten, the battery when it is a whole battery
period late. The side task waits at most SIDE_WAIT_S for slack, then runs anyway: a cue (let go,
balancing, a stop's tone) must reach the owner within a fraction of a human reaction time, and
one light write, note or datagram (0.1-0.45 ms) makes a tick at most slightly late, which the
overrun stop (time lost in a window) rides out. After a tick that skipped whole periods and
left a drive's live plan with no more than the 12 rows a skip keeps (KalmanCore.skip,
live_short), the side task is due at once: it makes the rows the skip took. (Not after every
skip: a side task called off its own rhythm after each of a realistic brick's late wake-ups
moved a course's corrections, and the square ended 10.7 cm from its start instead of 0.9.) Until the next tick with work due, a tick pays one integer
comparison for all of it.

The saturation stop: the law saturates a motor only for a moment while it balances (a push, a
stall caught up); a motor at its duty limit in config.SATURATED_SHARE of the ticks of the last
limits.max_saturated_s is a robot that no longer balances, whatever the estimate says: one that
fell while its gyro froze (the estimate still upright, the motors at full power on the floor),
that runs away on a wheel encoder that stopped counting, or that is blocked or held. The loop
then stops (Saturated, exit 6). The saturation flags of every SAT_SAMPLE-th row are counted once
a chunk, with the log's chunk, from the ring in memory: no tick pays for it. With it, a wheel whose encoder keeps
one count at every chunk's end for STUCK_S while its motor is driven hard (STUCK_DUTY_PCT) is a
dead encoder or a blocked wheel: DeviceFailure (exit 5), sooner than the saturation stop, which
a law with integral action and anti-windup may never reach on such a wheel.

Motors are not stopped here: the caller (tipbot_fw.session) stops them in its finally clause.
"""
import collections
import gc
import struct

from tipbot_fw.config import MAX_SATURATED_S, MAX_STALL_S, SATURATED_SHARE
from tipbot_fw.guard.heartbeat import NOT_SUPERVISED
from tipbot_fw.guard.plausibility import GYRO_MAX_DPS, EncoderBound, check_battery
from tipbot_fw.guard.realtime import ask_fifo
from tipbot_fw.guard.safety import (DeviceFailure, FallDetected, JointLimit, OverrunLimit, Saturated, Terminated,
                                    watchdog_stop)
from tipbot_fw.record import logfile
from tipbot_fw.vocabulary import FLAG_BITS, MOTOR_ROLES, SATURATION_BITS, SKIP_MAX, SKIP_SHIFT, WOUND_DOWN

# What a tick must leave before the next release for the work between ticks (a chunk of log rows
# is a copy, a CRC-32 and a pwrite; the battery one sysfs read, 0.3-0.45 ms on the brick), or
# SLACK_FRACTION of a period shorter than 5 ms (a 1 ms period still has its side tasks).
SLACK_S = 0.0015
SLACK_FRACTION = 0.3
# How long the side task waits for a tick with slack before it runs anyway: 50 ms, a quarter of
# an owner's reaction time to a light or a tone (about 0.2 s). With the paper's gains only about
# a quarter of the realistic brick's ticks leave SLACK_S, and cues came up to 0.14 s late.
SIDE_WAIT_S = 0.05
# How often the law's integrators are kept within their limit (KalmanCore.wind_down): the
# fixed-point range of the integrators is what they can gain in this long (tipbot_fw.cores.kalman,
# "Integral action"), whatever the battery's reading period
WIND_DOWN_S = 1.0

OVERRUN = FLAG_BITS['overrun']
FALL = FLAG_BITS['fall']
# The saturation stop reads every SAT_SAMPLE-th row's flags: a runaway or a robot fallen on its
# wheels saturates nearly every tick, a balancing robot at most a third of a second's (the
# module's docstring), so 20 samples a second tell them apart as well as 200 would
SAT_SAMPLE = 10
_FLAG = struct.Struct('<d')


# A wheel encoder that stops counting while its motor is driven (a cable pulled out, the motor's
# port dead) reads as a wheel that stands still: the law drives that wheel on and on while the
# robot rolls away upright. A balancing robot's wheels move: a duty of STUCK_DUTY_PCT (2.4 V of
# 8 V, six times a Large motor's friction duty) turns a free wheel several revolutions a second;
# the same count at the end of every log chunk for STUCK_S with that duty each time is a dead
# encoder or a blocked wheel (tipbot_fw.loop._watch_wheels: DeviceFailure, exit 5).
STUCK_DUTY_PCT = 25
STUCK_S = 0.75


def _wheel_slots(log):
    """(a Struct of a wheel pair, the byte offsets in a row of the wheels' counts and of their
    duties) in whichever core's row the log holds, or None if it has no such columns: two
    unpack_from calls a chunk read them (a numpy call costs the brick ~20,000 instructions)."""
    names = list(log.rows.mem_names)
    for counts, fmt in ((('rel_r', 'rel_l'), '<2q'), (('enc_r', 'enc_l'), '<2d')):
        if all(n in names for n in counts + ('duty_r', 'duty_l')):
            at = [8 * names.index(n) for n in counts + ('duty_r', 'duty_l')]
            if at[1] == at[0] + 8 and at[3] == at[2] + 8:
                return struct.Struct(fmt), at[0], at[2]
    return None


def _NEVER(k):
    """The side task of a loop without one: due again 2**29 ticks later (31 days at 5 ms), a
    tick number of one CPython digit (below 2**30), which compares fastest."""
    return k + (1 << 29)


class LoopStats(object):
    def __init__(self):
        self.ticks = 0
        self.overruns = 0
        self.max_consecutive_overruns = 0
        self.skipped_periods = 0
        self.max_lost_s = 0.0         # the most time lost within one overrun window
        self.max_saturated_share = 0.0  # the largest share of a saturation window's ticks a motor was saturated
        self.battery_reads = 0
        self.battery_v = None
        self.realtime = None

    def as_dict(self):
        return dict(self.__dict__)


def scheduling_line(info):
    """What the start says of the scheduling ask_fifo() got."""
    if info['granted']:
        return 'scheduling: SCHED_FIFO priority {}'.format(info['requested_priority'])
    if info['requested_priority'] <= 0:
        return 'scheduling: normal (no real-time priority asked for: realtime_priority 0)'
    return ('scheduling: normal, SCHED_FIFO priority {} refused ({}) for the loop and its supervisor: run '
            './install.sh --rtprio once on the brick (or start it as tipbot.service)'.format(
                info['requested_priority'], info['error']))


class ControlLoop(object):
    """Runs `core` on `devices` every period_s on `clock`, rows into the LogBuffer `log`.

    battery_v: the voltage read before start (re-read every battery_period_s); duration_s:
    stop after that many periods' worth of ticks (None: run until stopped); realtime_priority:
    SCHED_FIFO priority to ask for during the run (0: don't); heartbeat: the supervisor's page
    (tipbot_fw.guard.heartbeat); encoder_bound: a plausibility.EncoderBound (None: only the gyro's
    bound is checked); side: a side task (tipbot_fw.side_tasks) or None, settable until run();
    overrun_window_s, max_lost_s, max_stall_s: the overrun stop; max_saturated_s: the saturation
    stop (the module's docstring; inf: none); watch_wheels: the wheel watch (False: none);
    on_scheduling: called with one line saying which scheduling the run got, before the first tick.
    """

    def __init__(self, devices, core, clock, log, period_s, battery_v, battery_period_s=1.0,
                 overrun_window_s=0.3, max_lost_s=0.04, max_stall_s=MAX_STALL_S,
                 max_saturated_s=MAX_SATURATED_S, watch_wheels=True, duration_s=None, realtime_priority=0,
                 heartbeat=NOT_SUPERVISED,
                 encoder_bound=None, side=None, on_scheduling=None):
        self.devices = devices
        self.core = core
        self.clock = clock
        self.log = log
        self.period_s = period_s
        self.battery_v = battery_v
        self.battery_every = max(1, int(round(battery_period_s / period_s)))
        self.overrun_window_s = overrun_window_s
        self.max_lost_s = max_lost_s
        self.max_stall_s = max_stall_s
        self.max_saturated_s = max_saturated_s
        self.watch_wheels = watch_wheels
        self.n_ticks = None if duration_s is None else max(1, int(round(duration_s / period_s)))
        self.realtime_priority = realtime_priority
        self.heartbeat = heartbeat
        self.encoder_bound = encoder_bound
        self.side = side
        self.on_scheduling = on_scheduling
        self.stats = LoopStats()

    def run(self):
        """Run until duration_s is reached (returns LoopStats) or an exception stops it."""
        stats = self.stats
        stats.realtime, restore_sched = ask_fifo(self.realtime_priority)
        if self.on_scheduling is not None:
            self.on_scheduling(scheduling_line(stats.realtime))
        gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.disable()   # no collector pause inside a tick; the ticks create no reference cycles
        # Watched from the first tick on: the set-up since the calibration's last beat (the core,
        # the start cue, that gc.collect: about 8 million ARMv5 instructions, 30-60 ms on the
        # brick) is longer than the supervisor's stall timeout, and no motor has been driven yet.
        self.heartbeat.arm()
        try:
            self._run(stats)
        finally:
            if gc_was_enabled:
                gc.enable()
            restore_sched()
        return stats

    def _stop(self, k, flags):
        th1, th2, th3 = self.core.angles(self.log.mem[k % self.log.capacity])
        lim1, lim2, lim3 = self.core.limits
        if flags & FALL:
            raise FallDetected('fall: th1 = {:.3f} rad beyond limits.th1_rad = {} at tick {}'.format(
                th1, lim1, k))
        raise JointLimit('joint limit: th2 = {:.3f} rad, th3 = {:.3f} rad (limits {}, {}) at tick {}'.format(
            th2, th3, lim2, lim3, k))

    def _stopped_by_supervisor(self):
        # back from a stall the supervisor ended (motors stopped), before its SIGTERM arrived
        stopped = watchdog_stop(self.heartbeat)
        if stopped is not None:
            raise stopped

    def _behind(self, k, lost_s, late_s, longest_s):
        self._stopped_by_supervisor()
        skipped = int(round((lost_s - late_s) / self.period_s)) + int(late_s / self.period_s)
        raise OverrunLimit('the loop is behind: {:.1f} ms lost within {} s besides its longest hold of {:.1f} ms '
                           '(limits.max_lost_s = {} s within limits.overrun_window_s), {} periods skipped, tick {} '
                           'ended {:.1f} ms late'.format((lost_s - longest_s) * 1e3, self.overrun_window_s,
                                                         longest_s * 1e3, self.max_lost_s, skipped, k, late_s * 1e3))

    def _stalled(self, k, late_s, missed):
        self._stopped_by_supervisor()
        raise OverrunLimit('a stall of {:.1f} ms after tick {} ({} periods skipped), longer than limits.max_stall_s = '
                           '{} s: the longest the robot is designed to ride out'.format(
                               late_s * 1e3, k, missed, self.max_stall_s))

    def _run(self, stats):
        """The ticks: the hot path, written out with locals (attribute and global lookups cost
        real time on the brick); what a late tick and the housekeeping between ticks do are the
        cold methods _late_tick and _housekeeping (the side task, every tick for a remote, stays
        here)."""
        dev = self.devices
        read = dev.read_raw
        write = dev.write_duties
        now = self.clock.now
        sleep_until = self.clock.sleep_until
        core = self.core
        log = self.log
        buf = log.data
        cap = log.capacity
        pack_times = logfile.TIMES.pack_into
        row_bytes = log.row_bytes
        period = self.period_s
        n_ticks = -1 if self.n_ticks is None else self.n_ticks     # an int: compares faster than None
        hbt = self.heartbeat
        beat = hbt.words if hbt.words is not None else [0] * 8   # the same store either way
        bound = (self.encoder_bound or EncoderBound(None, None, period)).with_max_step(core.max_count_step)
        j2_tick = bound.per_tick ** 2
        j2_max = float('inf')           # tick 0 has no previous reading
        gyro_max = GYRO_MAX_DPS
        gyro_min = -gyro_max        # negated once: a negated int is a new object each time
        pa = pb = pc = pd = 0
        # the work between ticks: the side task's (every tick for a remote: here, as locals) and the
        # housekeeping's (the log's chunks, the battery, the integrators: a method), each due in its tick
        chores = self._plan_housekeeping()
        side = self.side
        side_due = 1
        if side is None:
            side, side_due = _NEVER, _NEVER(0)
        due = chores if chores < side_due else side_due
        min_slack = self._min_slack
        side_wait = max(1, int(round(SIDE_WAIT_S / period)))
        stats.battery_v = check_battery(self.battery_v)
        core.set_battery(self.battery_v)
        hbt.publish_rail(core.dlim)
        consecutive = 0
        step = core.start
        later = core.step       # bound once: a bound method made each tick costs it ~300 instructions
        k = 0       # ticks whose row is stored
        release = log.t0 = now()
        try:
            while True:
                t = now()
                try:
                    enc, gyro = read()
                except (OSError, ValueError) as e:
                    raise DeviceFailure('read_raw failed at tick {}: {}'.format(k, e))
                # the four jumps' squares against the bound's: a third cheaper than four chained
                # comparisons; it errs only towards the exact check (bound.check)
                a, b, c, d = enc
                a2 = a - pa
                b2 = b - pb
                c2 = c - pc
                d2 = d - pd
                if not (gyro_min <= gyro[1] <= gyro_max and a2 * a2 + b2 * b2 + c2 * c2 + d2 * d2 <= j2_max):
                    bound.check((pa, pb, pc, pd), enc, t - log.mem[(k - 1) % cap, 0], gyro[1], k)
                pa, pb, pc, pd = a, b, c, d
                beat[0] = k
                offset = (k % cap) * row_bytes
                duties, stop = step(enc, gyro, buf, offset)
                step = later
                j2_max = j2_tick
                if stop:
                    pack_times(buf, offset, t, now())
                    k += 1
                    self._stop(k - 1, stop)
                try:
                    write(duties)
                except (OSError, ValueError) as e:
                    raise DeviceFailure('write_duties failed at tick {}: {}'.format(k, e))
                pack_times(buf, offset, t, now())
                k += 1
                if k == n_ticks:
                    return
                release += period
                late = now() - release
                if late > 0.0:
                    release, consecutive = self._late_tick(k, late, release, consecutive)
                    if late >= period and side_due > k and core.live_short():
                        # periods skipped took a live plan's rows down to the few a skip keeps
                        # (KalmanCore.skip): its side task makes more, due at once (never later
                        # than it was: an overdue side task keeps its wait's start)
                        side_due = due = k
                else:
                    consecutive = 0
                if k >= due:        # work between ticks: one comparison a tick until some is due
                    if k >= chores:
                        chores = self._housekeeping(k, release)
                    if k >= side_due and (release - now() > min_slack or k - side_due >= side_wait):
                        side_due = side(k)
                    due = chores if chores < side_due else side_due
                sleep_until(release)   # returns at once when late
        finally:
            log.count = stats.ticks = k

    def _late_tick(self, k, late, release, consecutive):
        """Tick k - 1 ended `late` s after the next release: its row's flags (overrun, the whole
        periods missed), the counts, the overrun stop (the module's docstring), and the core
        predicted through the periods missed. -> (the next release, the overruns in a row)."""
        period = self.period_s
        stats = self.stats
        log = self.log
        skips = self._skips
        release_was = release
        missed = int(late / period)
        log.mem[(k - 1) % log.capacity, log.rows.flags_index] += OVERRUN + (min(missed, SKIP_MAX) << SKIP_SHIFT)
        stats.overruns += 1
        stats.skipped_periods += missed
        consecutive += 1
        if consecutive > stats.max_consecutive_overruns:
            stats.max_consecutive_overruns = consecutive
        while skips and skips[0][0] <= release_was - self.overrun_window_s:
            skips.popleft()
        lost = longest = late
        for _, skipped_s in skips:
            lost += skipped_s
            if skipped_s > longest:
                longest = skipped_s
        if late > self.max_stall_s:
            self._stalled(k - 1, late, missed)
        if lost - longest > stats.max_lost_s:
            stats.max_lost_s = lost - longest
        if lost - longest > self.max_lost_s:
            self._behind(k - 1, lost, late, longest)
        if missed:
            release += missed * period
            skips.append((release, missed * period))
            self.core.skip(missed)       # the model through the periods missed, duties held
        return release, consecutive

    def _plan_housekeeping(self):
        """The tick each part of the housekeeping between ticks (the module's docstring) is first
        due in -> the first tick with any."""
        period = self.period_s
        log = self.log
        self._skips = collections.deque()   # (release, seconds) of the periods skipped within the window
        self._next_flush = log.chunk_rows
        self._urgent = log.capacity - log.chunk_rows
        self._next_battery = self.battery_every
        self._wind_every = max(1, int(round(WIND_DOWN_S / period)))
        self._next_wind = self._wind_every
        self._min_slack = min(SLACK_S, SLACK_FRACTION * period)
        self._sat_from = 0          # the first tick the saturation stop has not counted yet
        self._sat_window = collections.deque()   # (ticks, rows sampled, [rows saturated per motor])
        self._sat_sums = [0, 0, [0] * len(MOTOR_ROLES)]     # the window's ticks, samples and counts
        self._sat_ticks = self.max_saturated_s / period
        self._wheels = _wheel_slots(log) if self.watch_wheels else None
        self._wheel_seen = []       # each chunk's end: ([wheel counts], [wheel duties], tick)
        return min(self._next_flush, self._next_battery, self._next_wind)

    def _housekeeping(self, k, release):
        """After tick k - 1's writes, the housekeeping that is due, each part in a tick that
        leaves slack before `release` or at once when it cannot wait (the module's docstring):
        the integrators' anti-windup, the log's chunks, the battery -> the next tick with any due."""
        log = self.log
        core = self.core
        now = self.clock.now
        min_slack = self._min_slack
        if k >= self._next_wind:        # the integrators' anti-windup, once a second, before the
            if core.wind_down():            # row it flags can go to the file
                log.mem[(k - 1) % log.capacity, log.rows.flags_index] += WOUND_DOWN
            self._next_wind = k - k % self._wind_every + self._wind_every
        if k >= self._next_flush and (release - now() > min_slack or k - log.flushed >= self._urgent):
            self._watch_wheels(k)               # the watches read the ring before the chunk goes
            self._watch_saturation(k)
            log.flush(k)                        # whole chunks: the file's unit
            self._next_flush = k - k % log.chunk_rows + log.chunk_rows
        battery_every = self.battery_every
        if k >= self._next_battery and (release - now() > min_slack or k - self._next_battery >= battery_every):
            self._read_battery(k)
            self._next_battery = k - k % battery_every + battery_every     # on the grid
        return min(self._next_flush, self._next_battery, self._next_wind)

    def _watch_saturation(self, k):
        """Count the saturation flags of every SAT_SAMPLE-th row stored since the last count (of
        those the ring still holds); Saturated if a motor was at its limit in SATURATED_SHARE of
        the samples of the last max_saturated_s (the module's docstring)."""
        log = self.log
        cap = log.capacity
        start = max(self._sat_from, k - cap)
        ticks = k - self._sat_from
        self._sat_from = k
        if ticks <= 0:
            return
        # every SAT_SAMPLE-th row's flags (on the tick grid), read with struct: no numpy call (one
        # costs the brick ~20,000 instructions) and nothing in the tick
        data, row_bytes, flags_at = log.data, log.row_bytes, 8 * log.rows.flags_index
        unpack = _FLAG.unpack_from
        r = l2 = j2 = j3 = sampled = 0
        for j in range(start + (-start) % SAT_SAMPLE, k, SAT_SAMPLE):
            low = int(unpack(data, (j % cap) * row_bytes + flags_at)[0]) & SATURATION_BITS
            sampled += 1
            if low:         # vocabulary: sat_r, sat_l, sat_th2, sat_th3 are bits 0-3, in MOTOR_ROLES
                # order; written out: a loop over the four bits costs the brick more
                r += low & 1
                l2 += (low >> 1) & 1
                j2 += (low >> 2) & 1
                j3 += low >> 3
        counts = [r, l2, j2, j3]
        # running sums of the window (a few list operations a chunk: no generator over it)
        window, sums = self._sat_window, self._sat_sums
        window.append((ticks, sampled, counts))
        sums[0] += ticks
        sums[1] += sampled
        total = sums[2]
        for i, c in enumerate(counts):
            total[i] += c
        while sums[0] - window[0][0] >= self._sat_ticks:
            old_ticks, old_rows, old_counts = window.popleft()
            sums[0] -= old_ticks
            sums[1] -= old_rows
            for i, c in enumerate(old_counts):
                total[i] -= c
        if sums[0] < self._sat_ticks or not max(total) or not sums[1]:
            return
        rows = float(sums[1])
        for i, c in enumerate(total):
            share = c / rows
            if share > self.stats.max_saturated_share:
                self.stats.max_saturated_share = share
            if share >= SATURATED_SHARE:
                raise Saturated('motor held at its limit: the {} motor at its duty limit in {:.0f} % of the ticks of the '
                                'last {:.2f} s (limits.max_saturated_s = {} s) up to tick {}: the robot no longer '
                                'balances (fallen while a sensor stopped, running away on an encoder that stopped '
                                'counting, blocked or held)'.format(MOTOR_ROLES[i], 100.0 * share, sums[0] * self.period_s,
                                                                   self.max_saturated_s, k - 1))

    def _watch_wheels(self, k):
        """A wheel encoder that stopped counting while its motor was driven (the module's
        docstring): its count at each chunk's end, the same for STUCK_S, and the wheel's duty at
        least STUCK_DUTY_PCT each time -> DeviceFailure. A few Python operations a chunk."""
        if self._wheels is None or k < 1:
            return
        pair, count_at, duty_at = self._wheels
        base = ((k - 1) % self.log.capacity) * self.log.row_bytes
        seen = self._wheel_seen
        seen.append((pair.unpack_from(self.log.data, base + count_at), pair.unpack_from(self.log.data, base + duty_at), k))
        while k - seen[0][2] > STUCK_S / self.period_s:
            seen.pop(0)
        if k - seen[0][2] < STUCK_S / self.period_s - 1:
            return
        for w, name in enumerate(('right', 'left')):
            if all(c[w] == seen[0][0][w] and abs(d[w]) >= STUCK_DUTY_PCT for c, d, _ in seen):
                raise DeviceFailure('the {} wheel\'s encoder read {} counts for {:.2f} s up to tick {} while its motor '
                                    'was driven at {} % duty or more: its cable is loose or the wheel is blocked'.format(
                                        name, seen[0][0][w], (k - seen[0][2]) * self.period_s, k - 1,
                                        STUCK_DUTY_PCT))

    def _read_battery(self, k):
        """The battery's reading after tick k - 1: plausible, the law rescaled when it changed;
        and whether the supervisor is still there."""
        stats = self.stats
        core = self.core
        hbt = self.heartbeat
        try:
            bv = self.devices.read_battery_v()
        except (OSError, ValueError) as e:
            raise DeviceFailure('battery read failed after tick {}: {}'.format(k - 1, e))
        check_battery(bv, stats.battery_v, 'after tick {}'.format(k - 1))
        stats.battery_reads += 1
        stats.battery_v = bv
        if bv != core.battery_v:
            core.set_battery(bv)
            hbt.publish_rail(core.dlim)
        if not hbt.supervisor_alive():
            raise Terminated('the supervisor (pid {}) is gone: the controller stopped the motors '
                             'itself'.format(hbt.supervisor_pid), 'supervisor_gone')
