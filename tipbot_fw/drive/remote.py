"""Driving from a remote: speed and turn commands over UDP, followed as a live drive plan.

`python3 -m tipbot_fw run ... --remote PORT` listens on UDP PORT for command datagrams
(docs/course-format.md, "Remote"), 16 bytes little-endian:

    magic b'TBDR', u32 seq, f32 speed_mps, f32 yaw_rate_dps

Which datagrams are obeyed: only those of one host, the one that started the run (the address
ssh says the session comes from, $SSH_CLIENT; without ssh, the first sender is taken and kept),
each with a sequence number above the last one obeyed (a stale or reordered datagram is
dropped), within the gains' limits (clipped to them: a remote's keys ask for 'faster' and get
the fastest allowed). With no command obeyed for TIMEOUT_S the command is zero: the robot
comes to rest and keeps balancing.

The reference is made in the loop's slack (a side task, tipbot_fw.side_tasks), LOOKAHEAD_TICKS ahead
of the ticks, a row at a time in scalar Python (about 32,000 instructions on the brick; with
numpy, whose every call costs about 20,000, one row was 540,000: more than the slack of a tick):
each change of a channel's command a smoothstep as a course's (tipbot_fw.drive.plan), a change that
arrives during another one waiting for it to end. The core copies one row a tick
(KalmanCore.set_live): the loop runs its side task at least every 10 ticks, and a stall's skip
leaves the plan 12 rows (tipbot_fw.cores.kalman.LIVE_KEEP_ROWS).

Python 3.5, standard library.
"""
import collections
import math
import socket
import struct

from tipbot_fw.drive.course import channel_limits, transition_s
from tipbot_fw.drive.plan import smoothstep
from tipbot_fw.cores.kalman import REF

MAGIC = b'TBDR'
COMMAND = struct.Struct('<4sIff')
TIMEOUT_S = 0.3
LOOKAHEAD_TICKS = 24        # beyond the loop's longest wait for its side task (10 ticks at 5 ms) and the 12 a skip keeps
MAX_DATAGRAMS = 32          # read in one call, at most


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
        self.seq = -1
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
        if seq <= self.seq or not (math.isfinite(speed) and math.isfinite(yaw_dps)):
            self.dropped['stale' if seq <= self.seq else 'malformed'] += 1
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


class LivePlan(object):
    """The reference rows of a remote's commands, made ahead of the ticks (module docstring)."""

    def __init__(self, limits, track_m, period_s, ref_lsb, top):
        fwd, yaw = channel_limits(limits)
        self.fwd = _Channel(limits['speed_mps'], fwd)
        self.yaw = _Channel(math.radians(limits['yaw_rate_dps']), yaw)
        self.track_m, self.dt, self.ref_lsb, self.top = track_m, period_s, ref_lsb, top
        self.rows = collections.deque()
        self.made = 0               # ticks made so far (the next row is tick made + 1's)

    def command(self, speed_mps, yaw_rate_rad_s):
        t = self.made * self.dt
        # one budget for both (as a course's segments): the turn gives way to the speed
        v_max, w_max = self.fwd.limit, self.yaw.limit
        speed = max(-v_max, min(v_max, speed_mps))
        room = max(0.0, 1.0 - abs(speed) / v_max) * w_max
        self.fwd.command(speed, t)
        self.yaw.command(max(-room, min(room, yaw_rate_rad_s)), t)

    def fill(self, ahead=LOOKAHEAD_TICKS):
        """Rows until `ahead` wait for the ticks (drive.reference_ints' arithmetic, a row at a time)."""
        n = ahead - len(self.rows)
        h = 0.5 * self.track_m
        l0, l1, l2, l3, l4, l5 = self.ref_lsb
        top = self.top
        for k in range(self.made + 1, self.made + 1 + n):
            t = k * self.dt
            s, v, a = self.fwd.advance(t, self.dt)
            psi, w, al = self.yaw.advance(t, self.dt)
            d_r = max(-top, min(top, int((s + psi * h) / l0)))
            d_l = max(-top, min(top, int((s - psi * h) / l1)))
            self.rows.append(REF.pack(d_r, d_l, int((v + w * h) / l2), int((v - w * h) / l3),
                                      int((a + al * h) / l4), int((a - al * h) / l5)))
        self.made += max(n, 0)


def live_plan(gains, core):
    """A Kalman core (with these gains) set to drive by a remote: -> its LivePlan, filled and
    handed to the core, whose rows remote_side() makes in the loop's slack."""
    ref = gains.kalman.reference
    plan = LivePlan(ref.limits, ref.track_m, gains.ts_s, core.ref_lsb, core.ref_pos_top)
    plan.fill()
    core.set_live(plan.rows)
    return plan


def remote_side(receiver, plan, period_s):
    """The side task: the newest command, then the rows ahead; called every tick it can be."""
    def task(k):
        plan.command(*receiver.poll(k * period_s))
        plan.fill()
        return k + 1
    return task
