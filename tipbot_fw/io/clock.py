"""Clocks for the control loop: the real one and a virtual one for tests and simulations.

The loop only calls now() and sleep_until(t), so a test can replace time itself and advance a
simulated robot in lock-step with the loop's sleeps.
"""
import time


class MonotonicClock(object):
    """Wall-clock-independent time: time.monotonic() and time.sleep()."""

    def __init__(self):
        self.now = time.monotonic   # the builtin itself: no Python frame per call

    def sleep_until(self, t):
        delay = t - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)


class VirtualClock(object):
    """Time that moves only when the loop sleeps (or when a test calls advance()).

    on_sleep(t_from, t_to), if given, is called before time jumps to t_to: a test uses it to
    integrate its plant, inject faults or jump time past a deadline (advance()).
    """

    def __init__(self, start=0.0, on_sleep=None):
        self.t = float(start)
        self.on_sleep = on_sleep
        self.sleeps = 0

    def now(self):
        return self.t

    def advance(self, dt):
        self.t += dt

    def sleep_until(self, t):
        self.sleeps += 1
        if self.on_sleep is not None:
            self.on_sleep(self.t, t)
        if t > self.t:
            self.t = t
