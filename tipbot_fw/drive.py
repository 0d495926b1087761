"""The drive reference: forward-speed and yaw-rate commands -> the wheels' reference, each tick.

A command (speed m/s, yaw rate rad/s, positive turning left) is not followed as a step: each of
its two channels (forward, yaw) moves its speed towards the command with the acceleration and
jerk the gains allow (`kalman.reference.limits`, hostsim.model.reference: derived from the
motors' voltage budget and the lean an acceleration needs), braking its acceleration early
enough not to overshoot. The wheels then follow

    d_r = s + psi H/2,   d_l = s - psi H/2     (s: distance, psi: heading, H: the track)

and their speeds and accelerations likewise. The core (tipbot_fw.kalman) takes them as six
integers per tick (the positions in 1/REF_POS_STEPS of a count, the rest in 2^-16 SI).

Cost: while both channels cruise (the command reached, nothing accelerating), a tick adds two
floats and packs six integers; only a tick that changes a speed runs the profile. A stall's
periods are followed (skip): the reference keeps to the clock, as the course's times do.

Course (tipbot_fw.course): a list of (speed, yaw rate, duration) segments from the let-go cue
(tick 0); after the last one the command is zero: the robot comes to rest and balances there.
Python 3.5, standard library only.
"""
import math


def _profile(v, a, target, a_max, j_max, dt):
    """One period of a speed channel -> (v, a): towards target, |a| <= a_max, |jerk| <= j_max.

    The acceleration aims at +-a_max while the speed still to go exceeds what bringing the
    acceleration back to zero at full jerk adds (a|a| / 2 j_max), at zero otherwise; the last
    small step lands on the target (no creeping around it)."""
    jdt = j_max * dt
    e = target - v
    if -jdt * dt <= e <= jdt * dt and -jdt <= a <= jdt:
        return target, 0.0
    # what bringing a to zero adds, in whole periods of j_max dt less each (a^2/2j + a dt/2),
    # and this period's own step
    to_go = e - a * abs(a) / (2.0 * j_max) - a * dt * 1.5
    want = a_max if to_go > 0.0 else -a_max
    if abs(to_go) < jdt * dt:
        want = 0.0
    da = want - a
    if da > jdt:
        da = jdt
    elif da < -jdt:
        da = -jdt
    a += da
    v += a * dt
    # a step that would cross the target at this acceleration stops on it
    if (target - v) * e < 0.0:
        v, a = target, 0.0
    return v, a


class DriveReference(object):
    """The reference of both wheels from speed and yaw-rate commands (module docstring).

    limits: the gains' `kalman.reference.limits` (speed_mps, accel_mps2, jerk_mps3,
    yaw_rate_dps, yaw_accel_dps2, yaw_jerk_dps3); track_m: H; period_s: the loop's; ref_lsb: SI
    per integer of each of the six (the core's ref_lsb); course: [(speed_mps, yaw_rate_rad_s,
    duration_s)] or None (commands from command(), e.g. a remote); top: the largest position
    integer the core takes."""

    def __init__(self, limits, track_m, period_s, ref_lsb, course=None, top=2 ** 31 - 1):
        self.dt = float(period_s)
        self.half = float(track_m) / 2.0
        self.v_max = limits['speed_mps']
        self.a_max = limits['accel_mps2']
        self.j_max = limits['jerk_mps3']
        self.w_max = math.radians(limits['yaw_rate_dps'])
        self.al_max = math.radians(limits['yaw_accel_dps2'])
        self.yj_max = math.radians(limits['yaw_jerk_dps3'])
        self.scale = [1.0 / lsb for lsb in ref_lsb]
        self.top = top
        self.s = self.v = self.a = 0.0         # forward: distance, speed, acceleration
        self.psi = self.w = self.al = 0.0       # yaw: heading, rate, acceleration
        self.v_cmd = self.w_cmd = 0.0
        self.settled = True
        self.ticks = 0
        self.course = list(course or [])
        self.segment = -1
        self.next_change = 0
        self._follow_course()

    def command(self, speed_mps, yaw_rate_rad_s):
        """Drive at this speed and yaw rate (clipped to the limits: a remote's keys ask for
        'faster' and get the fastest allowed; a course is refused beyond them before the run)."""
        self.v_cmd = max(-self.v_max, min(self.v_max, float(speed_mps)))
        self.w_cmd = max(-self.w_max, min(self.w_max, float(yaw_rate_rad_s)))
        self.settled = False

    def stop(self):
        """Come to rest (the profile's deceleration) and balance there."""
        self.command(0.0, 0.0)

    def _follow_course(self):
        while self.course and self.ticks >= self.next_change:
            self.segment += 1
            if self.segment >= len(self.course):
                self.course = []
                self.stop()
                return
            speed, yaw, duration = self.course[self.segment]
            self.command(speed, yaw)
            self.next_change += max(1, int(round(duration / self.dt)))

    def _period(self):
        self.ticks += 1
        if self.course and self.ticks >= self.next_change:
            self._follow_course()
        dt = self.dt
        if not self.settled:
            self.v, self.a = _profile(self.v, self.a, self.v_cmd, self.a_max, self.j_max, dt)
            self.w, self.al = _profile(self.w, self.al, self.w_cmd, self.al_max, self.yj_max, dt)
            self.settled = (self.v == self.v_cmd and self.w == self.w_cmd and self.a == 0.0 and self.al == 0.0)
        self.s += self.v * dt
        self.psi += self.w * dt

    def advance(self):
        """One period on -> the six integers of the core's reference for this tick."""
        self._period()
        return self._pack()

    def skip(self, periods):
        """The loop missed these periods: the reference moved on through them."""
        for _ in range(periods):
            self._period()

    def _pack(self):
        h = self.half
        sc = self.scale
        top = self.top
        # int() truncates: at most one integer (1/256 count, 2^-16 m/s) off, and cheaper than round()
        pr = int((self.s + self.psi * h) * sc[0])
        pl = int((self.s - self.psi * h) * sc[1])
        if not (-top <= pr <= top and -top <= pl <= top):
            # 5 km from the start: beyond the fixed-point range; hold the reference there
            pr, pl = max(-top, min(top, pr)), max(-top, min(top, pl))
        wh = self.w * h
        ah = self.al * h
        return (pr, pl, int((self.v + wh) * sc[2]), int((self.v - wh) * sc[3]),
                int((self.a + ah) * sc[4]), int((self.a - ah) * sc[5]))

    def state(self):
        """(distance m, heading rad, speed m/s, yaw rate rad/s) of the reference now."""
        return self.s, self.psi, self.v, self.w


def drive_for(gains, core, course=None):
    """The DriveReference of a Kalman core with these gains (their limits and track)."""
    ref = gains.kalman.reference
    return DriveReference(ref.limits, ref.track_m, gains.ts_s, core.ref_lsb, course, core.ref_pos_top)


def drive_problem(gains, config):
    """Why these gains and configuration cannot drive (one line), or None."""
    if config.get('estimator', 'kalman') != 'kalman':
        return 'driving needs the Kalman core (config estimator: kalman), not the paper\'s detector'
    if gains.kalman is None or gains.kalman.reference is None:
        return '{} has no drive reference (kalman.reference): gains made before driving; run make gains'.format(
            gains.path)
    return None
