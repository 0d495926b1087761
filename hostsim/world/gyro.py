"""The EV3 gyro as the brick reads it: late, sometimes frozen, scaled unevenly, drifting, in steps.

hostsim.world.sensors.SensorModel gives the ideal reading of today's simulations (the rate
and angle at the instant of the read, a constant bias, white noise, integer rounding).
:class:`GyroModel` adds, each switched on by its own parameter (scenario ``brick``
fields, realistic values in scenarios/brick_realistic.json with their sources):

- ``latency_s``: the reading reflects the robot that long ago (a G&A message takes about
  1 ms on the 57600-baud UART, plus the sensor's and the driver's own time);
- ``freeze_s`` / ``freeze_interval_s``: now and then (overruns start at exponential
  intervals of that mean, none during a freeze) a UART buffer overrun freezes the reading for
  ``freeze_s`` (about 42 ms), after which it jumps to the current value (the sensor resyncs);
  the start times do not depend on ``freeze_s`` while freezes do not overlap, so a longer
  freeze is the same run with longer freezes;
- ``scale_error``: (error for positive rates, error for negative rates) in the sensor's
  frame: a 360 deg turn one way reads about 353 deg (-2 %), the other way about 361;
- ``bias_walk_dps_rt_s`` and ``bias_ramp_dps_s``: the bias wanders (a random walk of that
  many deg/s per sqrt(s)) and drifts (that many deg/s per s), from t = 0 (when the
  simulation starts, before the firmware calibrates);
- ``rate_step_dps``: the rate reading moves in steps of that size (it stays constant for
  stretches and then jumps), instead of 1 deg/s.

The sensor integrates its own rate into its angle (value0) at the plant's 1 ms steps, so
bias, drift and scale errors reach the angle as they do on the sensor. :meth:`on_step` is
fed the true tilt rate at every plant step, :meth:`read` answers at any time.
Random draws (walk, freeze times) come from their own generator, so switching one effect
does not change the others' draws; the white noise uses the run's generator, as
SensorModel does.
"""
import collections
import math

GYRO_RATE_LIMIT_DPS = 440
_S16_MIN, _S16_MAX = -32768, 32767
_DEG = 180.0 / math.pi
_BLOCK = 4096


class GyroModel(object):
    def __init__(self, dt_s, gyro_sign=1, bias_dps=0.0, noise_dps=0.0, rng=None, fx_rng=None, latency_s=0.0,
                 freeze_s=0.0, freeze_interval_s=0.0, scale_error=(0.0, 0.0), bias_walk_dps_rt_s=0.0,
                 bias_ramp_dps_s=0.0, rate_step_dps=0.0):
        if noise_dps > 0 and rng is None:
            raise ValueError("gyro noise needs rng")
        if (bias_walk_dps_rt_s > 0 or (freeze_s > 0 and freeze_interval_s > 0)) and fx_rng is None:
            raise ValueError("gyro bias walk and freezes need fx_rng")
        self.dt_s = float(dt_s)
        self.sign = gyro_sign
        self.bias0 = float(bias_dps)
        self.noise = float(noise_dps)
        self.rng = rng
        self.fx_rng = fx_rng
        self.latency_s = float(latency_s)
        self.freeze_s = float(freeze_s)
        self.freeze_interval_s = float(freeze_interval_s)
        self.scale_pos = 1.0 + float(scale_error[0])
        self.scale_neg = 1.0 + float(scale_error[1])
        self.walk_step = float(bias_walk_dps_rt_s) * math.sqrt(self.dt_s)
        self.ramp = float(bias_ramp_dps_s)
        self.rate_step = float(rate_step_dps)
        self.walk = 0.0
        self._normals = []
        self.angle_deg = 0.0           # the sensor's own integral of what it measures
        self.t_s = 0.0
        self.rate_dps = 0.0            # what it measures now (before noise and rounding)
        # (t, measured rate, angle) at the last steps: as far back as the latency reaches
        self.history = collections.deque(maxlen=max(2, int(math.ceil(self.latency_s / self.dt_s)) + 2))
        self.history.append((0.0, 0.0, 0.0))
        self.freeze_start = self._next_freeze(0.0, 0.0)
        self.frozen = None             # (until, reading) during a freeze
        self.freezes = []              # (start, end) of every freeze so far

    def bias_dps(self, t_s):
        return self.bias0 + self.ramp * t_s + self.walk

    def _normal(self):
        if not self._normals:
            self._normals = self.fx_rng.standard_normal(_BLOCK).tolist()
        return self._normals.pop()

    def _next_freeze(self, start, end):
        """The next overrun after one from start to end."""
        if self.freeze_s > 0 and self.freeze_interval_s > 0:
            return max(start + float(self.fx_rng.exponential(self.freeze_interval_s)), end)
        return math.inf

    def on_step(self, t_s, th1_dot_rad_s):
        """The plant's state at the end of a step ending at t_s: its tilt rate (rad/s)."""
        if self.walk_step:
            self.walk += self.walk_step * self._normal()
        r = self.sign * th1_dot_rad_s * _DEG
        r = r * (self.scale_pos if r > 0.0 else self.scale_neg) + self.bias_dps(t_s)
        self.angle_deg += (t_s - self.t_s) * 0.5 * (r + self.rate_dps)     # trapezoid, as the plant's steps
        self.t_s = t_s
        self.rate_dps = r
        self.history.append((t_s, r, self.angle_deg))

    def _sample(self, t_s):
        """(rate, angle) of the last step at or before t_s - latency (the oldest kept if none)."""
        t = t_s - self.latency_s + 1e-9
        for entry in reversed(self.history):
            if entry[0] <= t:
                return entry[1], entry[2]
        return self.history[0][1], self.history[0][2]

    def read(self, t_s):
        """-> (angle_deg, rate_dps), the integers the sensor reports at t_s."""
        if self.frozen is not None:
            if t_s < self.frozen[0]:
                return self.frozen[1]
            self.frozen = None
        while t_s >= self.freeze_start:
            # an overrun at freeze_start: the reading from then on stays as it was
            until = self.freeze_start + self.freeze_s
            held = self._reading(self.freeze_start)
            self.freezes.append((self.freeze_start, until))
            self.freeze_start = self._next_freeze(self.freeze_start, until)
            if t_s < until:
                self.frozen = (until, held)
                return held
        return self._reading(t_s)

    def _reading(self, t_s):
        rate, angle = self._sample(t_s)
        if self.noise > 0:
            rate += self.noise * float(self.rng.standard_normal())
        if self.rate_step > 0:
            rate = self.rate_step * math.floor(rate / self.rate_step + 0.5)
        rate = int(math.floor(rate + 0.5))
        rate = min(max(rate, -GYRO_RATE_LIMIT_DPS), GYRO_RATE_LIMIT_DPS)
        angle = min(max(int(math.floor(angle + 0.5)), _S16_MIN), _S16_MAX)
        return angle, rate
