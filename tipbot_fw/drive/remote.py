"""Driving from a remote: speed and turn commands over UDP, followed as a live drive plan.

`python3 -m tipbot_fw run ... --remote PORT` listens on UDP PORT for command datagrams
(docs/course-format.md, "Remote"), 16 bytes little-endian:

    magic b'TBDR', u32 seq, f32 speed_mps, f32 yaw_rate_dps

Which datagrams are obeyed: only those of one host, the one that started the run (the address
ssh says the session comes from, $SSH_CLIENT; without ssh, the first sender is taken and kept),
each with a sequence number after the last one obeyed (a stale or reordered datagram is
dropped; "after" in serial-number arithmetic, RFC 1982, so the u32 wraps: a sender may start its
count anywhere, and ``tipbot-host drive`` starts it at its clock's milliseconds, so that a drive
program started again during a run is ahead of the one before it), within the gains' limits (clipped to them: a remote's keys ask for 'faster' and get
the fastest allowed). With no command obeyed for TIMEOUT_S the command is zero: the robot
comes to rest and keeps balancing.

The reference is made in the loop's slack (a side task, tipbot_fw.side_tasks), in scalar Python
(with numpy, whose every call costs the brick about 20,000 instructions, a row was 540,000): each
change of a channel's command a smoothstep as a course's (tipbot_fw.drive.plan), a change that
arrives during another one waiting for it to end. The side task comes every POLL_TICKS: it
polls the receiver, takes a command to the plan only when it changed, and makes rows in
batches up to LOOKAHEAD_TICKS ahead when they run low. While both channels keep a constant rate
(no change under way: the usual case, a key held or none) the rows are made by additions, in C
(_SteadyRows: about 4,000 instructions a row against 30,000 through the smoothsteps), so a
driven tick costs little more than a course's (`make bench`, docs/benchmarks.md). The core takes
one row a tick (KalmanCore.set_live); a stall's skip leaves the plan 12 rows
(tipbot_fw.cores.kalman.LIVE_KEEP_ROWS) and the loop then calls the side task at once. A command
reaches the rows after those already made: 14 to 28 ticks (70-140 ms), besides the poll's 20 ms.

Python 3.5, standard library.
"""
import collections
import math
import socket
import struct
from itertools import accumulate, chain, repeat

from tipbot_fw.drive.course import channel_limits, transition_s
from tipbot_fw.drive.plan import smoothstep
from tipbot_fw.cores.kalman import REF

MAGIC = b'TBDR'
COMMAND = struct.Struct('<4sIff')
TIMEOUT_S = 0.3
# The side task comes every POLL_TICKS (20 ms at 5 ms: a key's or a datagram's latency, not a
# tick's) and then makes rows up to LOOKAHEAD_TICKS ahead if fewer than REFILL_BELOW would be left
# at its next call: batches of 11 or more. REFILL_BELOW is beyond the loop's longest wait for its
# side task (10 ticks at 5 ms); a stall's skip leaves 12 rows (kalman.LIVE_KEEP_ROWS), after which
# the loop calls the side task at once (tipbot_fw.loop)
LOOKAHEAD_TICKS = 28
REFILL_BELOW = 14
POLL_TICKS = 4
MAX_DATAGRAMS = 32          # read in one call, at most
SEQ_MODULUS = 1 << 32       # the datagram's u32


def is_after(seq, last):
    """Whether sequence number ``seq`` comes after ``last`` (None: nothing obeyed yet), in
    serial-number arithmetic (RFC 1982): less than half the u32's range ahead, modulo 2**32."""
    return last is None or 0 < (seq - last) % SEQ_MODULUS < SEQ_MODULUS // 2


class RemoteError(ValueError):
    """A --remote port that cannot be listened on."""


def allowed_host(environ):
    """The host that started the run over ssh ($SSH_CLIENT: 'address port port'), or None."""
    client = environ.get('SSH_CLIENT', '').split()
    return client[0] if client else None


class Receiver(object):
    """The command datagrams of one host (module docstring); poll(now_s) -> (speed_mps,
    yaw_rate_rad_s) now. Counts what it dropped: stale, foreign, malformed."""

    def __init__(self, port, host=None, sock=None):
        self.sock = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if sock is None:
            try:
                self.sock.bind(('', int(port)))
            except (OSError, ValueError) as e:
                self.sock.close()
                raise RemoteError('--remote {}: {}'.format(port, e))
        self.sock.setblocking(False)
        self.host = host
        self.seq = None
        self.command = (0.0, 0.0)
        self.last_s = None
        self.dropped = {'stale': 0, 'foreign': 0, 'malformed': 0}
        self.obeyed = 0

    def poll(self, now_s):
        for _ in range(MAX_DATAGRAMS):
            try:
                data, address = self.sock.recvfrom(64)
            except OSError:        # nothing more (BlockingIOError), or an error: nothing new
                break
            self._take(data, address[0], now_s)
        if self.last_s is None or now_s - self.last_s > TIMEOUT_S:
            return 0.0, 0.0
        return self.command

    def _take(self, data, host, now_s):
        if len(data) != COMMAND.size or data[:4] != MAGIC:
            self.dropped['malformed'] += 1
            return
        if self.host is None:
            self.host = host        # the first sender, kept for the run
        if host != self.host:
            self.dropped['foreign'] += 1
            return
        _, seq, speed, yaw_dps = COMMAND.unpack(data)
        after = is_after(seq, self.seq)
        if not after or not (math.isfinite(speed) and math.isfinite(yaw_dps)):
            self.dropped['malformed' if after else 'stale'] += 1
            return
        self.seq = seq
        self.command = (float(speed), math.radians(yaw_dps))
        self.last_s = now_s
        self.obeyed += 1

    def summary(self):
        return {'host': self.host, 'obeyed': self.obeyed, 'dropped': dict(self.dropped)}

    def close(self):
        self.sock.close()


class _Channel(object):
    """One channel (forward or yaw) of the live plan: its rate moves to each new command along a
    smoothstep; a command during a change waits for its end."""

    def __init__(self, limit, lim):
        self.limit = limit
        self.a_max, self.j_max = lim
        self.v0 = self.dv = 0.0
        self.t0 = self.T = 0.0
        self.pending = None
        self.pos = 0.0
        self.last_rate = 0.0

    def command(self, target, t_s):
        target = max(-self.limit, min(self.limit, target))
        if t_s < self.t0 + self.T:
            self.pending = target
            return
        self._start(target, t_s)

    def _start(self, target, t_s):
        final = self.v0 + self.dv
        self.pending = None
        if target != final:
            self.v0, self.dv = final, target - final
            self.T = transition_s(self.dv, self.a_max, self.j_max)
            self.t0 = t_s

    def advance(self, t, dt):
        """(position, rate, acceleration) at time t, one tick of dt after the last call: scalar
        Python (module docstring: a numpy call costs the brick ~20,000 instructions)."""
        if self.pending is not None and t >= self.t0 + self.T:
            self._start(self.pending, self.t0 + self.T)
        if self.T > 0.0:
            x = min(1.0, max(0.0, (t - self.t0) / self.T))
            d_rate, acc = smoothstep(x, self.dv, self.T)
            rate = self.v0 + d_rate
        else:
            rate, acc = self.v0 + self.dv, 0.0
        self.pos += 0.5 * (self.last_rate + rate) * dt
        self.last_rate = rate
        return self.pos, rate, acc

    def steady_from(self, t):
        """The constant rate of every tick from time t on, if nothing changes it before a new
        command (no change under way or waiting, and the last tick's rate already that one), or
        None. Then advance() is position += rate dt and acceleration 0 (smoothstep at x = 1:
        the whole change, no acceleration)."""
        if self.pending is not None or t < self.t0 + self.T:
            return None
        rate = self.v0 + self.dv
        return rate if rate == self.last_rate else None


class _SteadyRows(object):
    """The rows of both channels at constant rates v, w (rad/s) from positions s, psi: each
    wheel's position advanced by a constant step in its integers, the speeds' integers made
    once, the accelerations' zero; the additions, the conversions and the packing in C
    (itertools, map), for a Python loop's bytecodes would be most of a row's cost. `left`: the
    rows it may make before a position leaves the fixed-point range (+-top: 5 km out), after
    which the rows are made one at a time, clipped."""

    def __init__(self, s, psi, v, w, dt, h, lsb, top):
        self.s, self.psi, self.ds, self.dpsi = s, psi, v * dt, w * dt
        self.made = 0
        l0, l1, l2, l3, _, _ = lsb
        self.r, self.r_step = (s + psi * h) / l0, (self.ds + self.dpsi * h) / l0
        self.l, self.l_step = (s - psi * h) / l1, (self.ds - self.dpsi * h) / l1
        self.v_r, self.v_l = int((v + w * h) / l2), int((v - w * h) / l3)
        room = [(top - abs(x)) / abs(step) for x, step in ((self.r, self.r_step), (self.l, self.l_step)) if step]
        self.left = int(max(0.0, min(room))) if room else 1 << 62

    def make(self, n):
        """An iterator of the next n rows (bytes)."""
        r, l, r_step, l_step = self.r, self.l, self.r_step, self.l_step
        d_r = map(int, accumulate(chain((r + r_step,), repeat(r_step, n - 1))))
        d_l = map(int, accumulate(chain((l + l_step,), repeat(l_step, n - 1))))
        self.r, self.l = r + n * r_step, l + n * l_step
        self.made += n
        self.left -= n
        return map(REF.pack, d_r, d_l, repeat(self.v_r), repeat(self.v_l), repeat(0), repeat(0))

    def positions(self):
        """(s, psi) after the rows made."""
        return self.s + self.made * self.ds, self.psi + self.made * self.dpsi


class LivePlan(object):
    """The reference rows of a remote's commands, made ahead of the ticks (module docstring)."""

    def __init__(self, limits, track_m, period_s, ref_lsb, top):
        fwd, yaw = channel_limits(limits)
        self.fwd = _Channel(limits['speed_mps'], fwd)
        self.yaw = _Channel(math.radians(limits['yaw_rate_dps']), yaw)
        self.track_m, self.dt, self.ref_lsb, self.top = track_m, period_s, ref_lsb, top
        self.rows = collections.deque()
        self.made = 0               # ticks made so far (the next row is tick made + 1's)
        self.steady = None          # the _SteadyRows both channels are making, if they are steady

    def command(self, speed_mps, yaw_rate_rad_s):
        self._leave_steady()
        t = self.made * self.dt
        # one budget for both (as a course's segments): the turn gives way to the speed
        v_max, w_max = self.fwd.limit, self.yaw.limit
        speed = max(-v_max, min(v_max, speed_mps))
        room = max(0.0, 1.0 - abs(speed) / v_max) * w_max
        self.fwd.command(speed, t)
        self.yaw.command(max(-room, min(room, yaw_rate_rad_s)), t)

    def fill(self, ahead=LOOKAHEAD_TICKS):
        """Rows until `ahead` wait for the ticks (drive.reference_ints' arithmetic): while both
        channels are steady by additions (module docstring, _SteadyRows), else a row at a time."""
        n = ahead - len(self.rows)
        if n <= 0:
            return
        first = self.made + 1
        self.made += n
        run = self.steady
        if run is None:
            run = self.steady = self.steady_rows(first * self.dt)
        if run is not None and run.left >= n:
            self.rows.extend(run.make(n))
        else:
            self._leave_steady()
            self._rows_changing(first, n)

    def steady_rows(self, t):
        """The _SteadyRows of the plan from time t on, or None if a channel is changing."""
        v, w = self.fwd.steady_from(t), self.yaw.steady_from(t)
        if v is None or w is None:
            return None
        return _SteadyRows(self.fwd.pos, self.yaw.pos, v, w, self.dt, 0.5 * self.track_m, self.ref_lsb, self.top)

    def _leave_steady(self):
        """The channels' positions where the steady rows left them (a change, or the range's end)."""
        if self.steady is not None:
            self.fwd.pos, self.yaw.pos = self.steady.positions()
            self.steady = None

    def _rows_changing(self, first, n):
        """n rows from tick `first`, a channel changing its rate: each through its smoothstep."""
        h = 0.5 * self.track_m
        l0, l1, l2, l3, l4, l5 = self.ref_lsb
        top = self.top
        dt = self.dt
        fwd, yaw = self.fwd.advance, self.yaw.advance
        pack, append = REF.pack, self.rows.append
        for k in range(first, first + n):
            t = k * dt
            s, v, a = fwd(t, dt)
            psi, w, al = yaw(t, dt)
            d_r = max(-top, min(top, int((s + psi * h) / l0)))
            d_l = max(-top, min(top, int((s - psi * h) / l1)))
            append(pack(d_r, d_l, int((v + w * h) / l2), int((v - w * h) / l3),
                        int((a + al * h) / l4), int((a - al * h) / l5)))


def live_plan(gains, core):
    """A Kalman core (with these gains) set to drive by a remote: -> its LivePlan, filled and
    handed to the core, whose rows remote_side() makes in the loop's slack."""
    ref = gains.kalman.reference
    plan = LivePlan(ref.limits, ref.track_m, gains.ts_s, core.ref_lsb, core.ref_pos_top)
    plan.fill()
    core.set_live(plan.rows)
    return plan


def remote_side(receiver, plan, period_s):
    """The side task, every POLL_TICKS: the newest command (to the plan only when it changed),
    then the rows ahead if fewer than REFILL_BELOW would be left at its next call."""
    last = [None]

    def task(k):
        command = receiver.poll(k * period_s)
        if command != last[0]:
            last[0] = command
            plan.command(*command)
        if len(plan.rows) < REFILL_BELOW + POLL_TICKS:
            plan.fill()
        return k + POLL_TICKS
    return task
