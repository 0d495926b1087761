"""What the robot tells its owner, in words, lights and tones: hold it still, let go, it balances,
the battery is low, why it stopped. One place for all of it.

Held exactly at the start pose the estimate is zero and the wheels do not move, so "let go when
the wheels drive" cannot be the cue: the firmware says when.

Words go to stdout (brickrun and brickman's File Browser show a program's stdout on the
brick's screen) and to stderr (with the firmware's other messages, over ssh: `make run`), once
if both are the same terminal. Started over ssh (SSH_CONNECTION in the environment) stdout is
not the brick's screen but a second channel of the same session: the words go to stderr only.
Why a run stopped is already on stderr (the session's "stopped:" line), so its short form goes
to the screen only.

Lights and tones (tipbot_fw.io.lights_speaker; each state's light pair and melody are there) never touch
a control tick: "hold" plays before the gyro calibration, a stop reason after the motors are
stopped and the log is written, both blocking. "let go" sets its lights and starts its first
note right before the first tick; the rest of its melody, "balancing" (after BALANCING_AFTER_S of
running) and the low-battery warning are played by LoopCues in the loop's slack (after a tick's
writes, tipbot_fw.loop), at most one write per tick.
"""
import math
import os
import sys

from tipbot_fw.io.lights_speaker import stop_state

# The loop has run this long: tell the owner the robot balances.
BALANCING_AFTER_S = 1.0

# A stop reason's short words for the screen (any other reason: 'stopped: <reason>').
STOP_WORDS = {
    'completed': 'DONE: ran its duration', 'fall': 'STOPPED: fell over', 'joint_limit': 'STOPPED: joint limit',
    'saturated': 'STOPPED: motor held at its limit',
    'device_failure': 'STOPPED: sensor/motor failed', 'overruns': 'STOPPED: ticks late (overruns)',
    'low_battery': 'NOT STARTED: battery low, charge it', 'calibration': 'NOT STARTED: moved while calibrating',
    'devices': 'NOT STARTED: devices missing', 'keyboard_interrupt': 'STOPPED: Ctrl-C',
    'sigterm': 'STOPPED: terminated', 'signal': 'STOPPED: a signal', 'exception': 'STOPPED: error (a bug)',
    'battery_implausible': 'STOPPED: battery reading bad', 'watchdog': 'STOPPED: stalled (supervisor)',
    'supervisor_gone': 'STOPPED: supervisor gone', 'controller_died': 'STOPPED: crashed (supervisor)',
}


class OwnerCues(object):
    """``streams``: where the words go; None: sys.stdout and sys.stderr as they are when a cue
    is given (only stderr with screen=False: --quiet); () for no words. ``brick``: a
    tipbot_fw.io.lights_speaker.BrickSignals for the lights and tones, or None (no brick, --quiet,
    simulations)."""

    def __init__(self, streams=None, brick=None, screen=True):
        self.streams = streams
        self.brick = brick
        self.screen = screen
        self.pending = []       # the let-go melody's rest, for the loop's slack: [(t_s, target, value)]

    def hold_still(self, seconds):
        """Before the gyro calibration: the robot must be held still and upright."""
        self._show('HOLD the robot still and upright: calibrating the gyro ({:.1f} s)'.format(seconds))
        self._signal('hold')

    def let_go(self):
        """The calibration is done and the first control tick comes next: lights and the first
        note now, the rest of the melody in the loop's slack (in_loop)."""
        if self.brick is not None:
            plan = self.brick.plan('let_go')
            for t, target, value in plan:
                if t == 0.0:
                    self.brick.apply(target, value)
            self.pending = [p for p in plan if p[0] > 0.0]
        self._show('LET GO NOW: balancing')

    def in_loop(self, loop, warn_battery_v):
        """The side task (tipbot_fw.side_tasks) that gives the cues while `loop` runs."""
        return LoopCues(self, loop.period_s, loop.battery_every, loop.stats, warn_battery_v)

    def battery_warning(self, battery_v, warn_battery_v):
        self._show('BATTERY LOW: {:.2f} V (limits.warn_battery_v {} V): charge it soon'.format(
            battery_v, warn_battery_v))

    def stopped(self, reason, code):
        """After the motors are stopped and the log is written: why, on the screen, with its
        light and melody (blocking, up to a second)."""
        self._show('{} (exit {})'.format(STOP_WORDS.get(reason, 'stopped: ' + reason), code), screen_only=True)
        self._signal(stop_state(reason))

    def close(self):
        if self.brick is not None:
            self.brick.close()

    def _signal(self, state):
        if self.brick is not None:
            self.brick.show(state)

    def _show(self, text, screen_only=False):
        line = 'tipbot: {}\n'.format(text)
        for stream in self._targets(screen_only):
            try:
                stream.write(line)
                stream.flush()
            except (OSError, ValueError):    # a closed or vanished console must not stop the robot
                pass

    def _targets(self, screen_only):
        if self.streams is not None:
            return self.streams
        on_screen = self.screen and not os.environ.get('SSH_CONNECTION')
        out, err = sys.stdout if on_screen else None, sys.stderr
        if out is None or err is None or _same_file(out, err):
            return [] if screen_only else [s for s in (err, out) if s is not None][:1]
        return [out] if screen_only else [out, err]


def _same_file(a, b):
    try:
        return os.path.samestat(os.fstat(a.fileno()), os.fstat(b.fileno()))
    except (AttributeError, OSError, ValueError):    # no file descriptor (captured output)
        return False


class LoopCues(object):
    """The cues given while the loop runs, as a side task (tipbot_fw.side_tasks): called with k, the
    ticks done, it does at most one light or tone write that is due and returns the tick at
    which it wants to be called next. Times become ticks of period_s; the battery is the
    loop's own reading (stats.battery_v), checked about once a battery period (every
    battery_every ticks: a call the loop made late for want of slack checks it too)."""

    def __init__(self, cues, period_s, battery_every, stats, warn_battery_v):
        self.cues = cues
        self.brick = cues.brick
        self.period_s = period_s
        self.stats = stats
        self.warn_battery_v = warn_battery_v
        self.queue = self._ticks(cues.pending, 0)
        cues.pending = []
        self.balancing_at = max(1, int(round(BALANCING_AFTER_S / period_s)))
        self.battery_every = battery_every
        self.next_check = min(self.balancing_at, battery_every)
        self.balancing = self.warned = False

    def _ticks(self, plan, k):
        # ceil, but a time that is a whole number of periods up to round-off is that number
        return [(k + int(math.ceil(t / self.period_s - 1e-6)), target, value) for t, target, value in plan]

    def _queue(self, state, k):
        """Show `state` from tick k on, in place of whatever was still queued."""
        if self.brick is not None:
            self.queue = self._ticks(self.brick.plan(state), k)

    def _check(self, k):
        if not self.balancing and k >= self.balancing_at:
            self.balancing = True
            self._queue('battery_warning' if self.warned else 'balancing', k)
        bv = self.stats.battery_v
        if not self.warned and bv is not None and bv < self.warn_battery_v:
            self.warned = True
            self.cues.battery_warning(bv, self.warn_battery_v)
            self._queue('battery_warning', k)
        nxt = (k // self.battery_every + 1) * self.battery_every
        self.next_check = self.balancing_at if k < self.balancing_at < nxt else nxt

    def __call__(self, k):
        if k >= self.next_check:
            self._check(k)
        q = self.queue
        if q and q[0][0] <= k:
            _, target, value = q.pop(0)
            self.brick.apply(target, value)
        if q and q[0][0] < self.next_check:
            return max(q[0][0], k + 1)
        return self.next_check


QUIET = OwnerCues(streams=())
