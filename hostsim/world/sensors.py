"""Sensor models: the plant's state -> the raw integers the EV3 devices would report.

Raw means what tipbot_fw.io.devices passes on untouched: encoder counts as each encoder counts
them, the gyro in its own frame. The signal chain undoes the mounting with the configured
polarities and gyro sign, so ``motor_signs`` and ``gyro_sign`` here are the physical facts those
config fields must match.

* Wheel encoders sit on link 1, so they measure the wheel angle RELATIVE to link 1:
  phi_rel = d / R_w - th1 (rad). Joint encoders measure th2, th3 (each relative to the link
  below), 1:1.
* counts = floor(sign * angle / step + 0.5), step = 1/360 turn: an incremental encoder counts
  the edges it has passed, i.e. floor; the +0.5 puts the simulation's angle zero halfway
  between two edges (where on the disc the real zero falls is unknown), so a motor at rest
  near its start pose reads a steady 0 instead of dithering across an edge, and the error is
  +-half a count.
* Gyro (EV3 gyro in GYRO-G&A): rate = sign * th1_dot + bias + noise, rounded to integer deg/s
  and clipped to +-440 deg/s (the sensor's range); angle = sign * th1 + bias * t, rounded to
  integer degrees: the sensor integrates its own (biased) rate, so the bias drifts the angle.
  The rate noise is not integrated into the angle (the sensor integrates at a much higher
  rate, which averages it out). hostsim.world.fake_ev3 restarts the angle at the mode switch, as
  the sensor does; its absolute offset here does not matter.
* Battery: open-circuit voltage minus internal resistance times the current drawn.

Scalar Python on purpose: called once per 5 ms simulation step.
"""

import math

COUNTS_PER_ROT = 360
GYRO_RATE_LIMIT_DPS = 440
_S16_MIN, _S16_MAX = -32768, 32767
_DEG = 180.0 / math.pi


def _counts(angle_rad, sign, counts_per_rot):
    return counts_of(angle_rad, sign, counts_per_rot, False)


class SensorModel(object):
    """Raw EV3 readings from a state x = [d_r, d_l, th1, th2, th3, d_r_dot, d_l_dot, th1_dot,
    th2_dot, th3_dot] (SI: m, rad, m/s, rad/s).

    motor_signs: +1/-1 per motor (right wheel, left wheel, joint 2, joint 3): +1 if the encoder
    counts up when the wheel rolls forward / the joint angle grows. gyro_sign: +1 if the gyro
    reads positive for a forward tilt. gyro_noise_dps > 0 needs ``rng`` (a numpy Generator).
    """

    def __init__(self, wheel_radius_m, motor_signs=(1, 1, 1, 1), gyro_sign=1,
                 gyro_bias_dps=0.0, gyro_noise_dps=0.0, rng=None,
                 counts_per_rot=(COUNTS_PER_ROT,) * 4, battery_v=8.0, battery_r_ohm=0.0):
        if wheel_radius_m <= 0:
            raise ValueError('wheel_radius_m must be > 0, got {!r}'.format(wheel_radius_m))
        for s in tuple(motor_signs) + (gyro_sign,):
            if s not in (1, -1):
                raise ValueError('signs must be +1 or -1, got {!r}'.format(s))
        if len(motor_signs) != 4 or len(counts_per_rot) != 4:
            raise ValueError('motor_signs and counts_per_rot need 4 entries (r, l, th2, th3)')
        if gyro_noise_dps < 0:
            raise ValueError('gyro_noise_dps must be >= 0, got {!r}'.format(gyro_noise_dps))
        if gyro_noise_dps > 0 and rng is None:
            raise ValueError('gyro_noise_dps > 0 needs rng (numpy.random.Generator)')
        self.wheel_radius_m = float(wheel_radius_m)
        self.motor_signs = tuple(motor_signs)
        self.counts_per_rot = tuple(counts_per_rot)
        self.gyro_sign = gyro_sign
        self.gyro_bias_dps = float(gyro_bias_dps)
        self.gyro_noise_dps = float(gyro_noise_dps)
        self.rng = rng
        self.battery_v = float(battery_v)
        self.battery_r_ohm = float(battery_r_ohm)

    def encoders(self, x):
        """-> (enc_r, enc_l, enc_2, enc_3) integer counts."""
        th1 = x[2]
        rw = self.wheel_radius_m
        s = self.motor_signs
        n = self.counts_per_rot
        return (_counts(x[0] / rw - th1, s[0], n[0]),
                _counts(x[1] / rw - th1, s[1], n[1]),
                _counts(x[3], s[2], n[2]),
                _counts(x[4], s[3], n[3]))

    def gyro(self, x, t_s):
        """-> (angle_deg, rate_dps) integers at time t_s (s, for the bias drift of the angle)."""
        sign = self.gyro_sign
        bias = self.gyro_bias_dps
        rate = sign * x[7] * _DEG + bias
        if self.gyro_noise_dps > 0:
            rate += self.gyro_noise_dps * float(self.rng.standard_normal())
        rate = int(math.floor(rate + 0.5))
        rate = min(max(rate, -GYRO_RATE_LIMIT_DPS), GYRO_RATE_LIMIT_DPS)
        angle = int(math.floor(sign * x[2] * _DEG + bias * t_s + 0.5))
        angle = min(max(angle, _S16_MIN), _S16_MAX)
        return angle, rate

    def battery(self, current_a=0.0):
        """Battery voltage (V) while ``current_a`` amperes are drawn."""
        return self.battery_v - self.battery_r_ohm * current_a

    def read(self, x, t_s, current_a=0.0):
        """-> (encoder counts, (gyro angle, rate), battery volts): one simulation step's readings,
        in the form FakeEV3.set_readings takes."""
        return self.encoders(x), self.gyro(x, t_s), self.battery(current_a)


def counts_of(angle_rad, sign, counts_per_rot, truncate):
    """Encoder counts of an angle: the edges passed (floor) with the start pose on an edge
    (``truncate``, as the EV3's driver counts), or halfway between two (rounding, above)."""
    return int(math.floor(sign * angle_rad * counts_per_rot / (2.0 * math.pi) + (0.0 if truncate else 0.5)))


class EncoderModel(object):
    """The four tacho encoders as the EV3 driver reports them: ``position`` is updated every
    ``update_s`` (the PRU's 2 ms; 0: read at the instant of the read) and, with ``truncate``,
    counts whole edges passed instead of rounding to the nearest count.

    on_step(k, angles) is fed every plant step k (of dt_s) with the motors' angles (the
    rotors', hostsim.world.drivetrain); read(angles) gives the counts a read sees now."""

    def __init__(self, motor_signs, counts_per_rot, dt_s, update_s=0.0, truncate=False):
        self.signs = tuple(motor_signs)
        self.cpr = tuple(counts_per_rot)
        self.truncate = bool(truncate)
        self.every = int(round(update_s / dt_s)) if update_s > 0 else 0
        if update_s > 0 and (self.every < 1 or abs(self.every * dt_s - update_s) > 1e-9):
            raise ValueError("encoder update period %r s is not a multiple of the plant step %r s" % (update_s, dt_s))
        self.latched = None

    def counts(self, angles):
        s, n, tr = self.signs, self.cpr, self.truncate
        return tuple(counts_of(angles[i], s[i], n[i], tr) for i in range(4))

    def on_step(self, k, angles):
        if self.every and k % self.every == 0:
            self.latched = self.counts(angles)

    def read(self, angles):
        if self.every and self.latched is not None:
            return self.latched
        return self.counts(angles)


class BatteryModel(object):
    """The battery under the motors' load, as ``voltage_now`` reports it: the one battery model
    of the simulated worlds (the balancing robot's, hostsim.world.lockstep, and the
    identification bench's, hostsim.sim.motor_sim).

    The H-bridges draw, from the battery, each motor's current times its duty, and the motor's
    current is (duty x V - Ke omega) / Ra; the brick itself draws ``idle_a``; with the internal
    resistance r the terminal voltage V solves V = V_oc - r (idle_a + sum(d_i (d_i V - Ke_i
    omega_i) / Ra_i)), i.e. V = (V_oc - r idle_a + r sum(d_i Ke_i omega_i / Ra_i)) / (1 + r
    sum(d_i^2 / Ra_i)). The reading is quantized down to ``quantum_v`` (2.44 mV steps of the
    ADC)."""

    def __init__(self, v_oc, r_ohm=0.0, quantum_v=0.0, ke_v_s=(0.0,) * 4, ra_ohm=(1.0,) * 4, idle_a=0.0):
        self.v_oc = float(v_oc) - float(r_ohm) * float(idle_a)      # the source the motors see
        self.r = float(r_ohm)
        self.quantum = float(quantum_v)
        self.ke_ra = [k / r for k, r in zip(ke_v_s, ra_ohm)]
        self.inv_ra = [1.0 / r for r in ra_ohm]

    def voltage(self, fractions, speeds):
        """Terminal voltage (V) with duty fractions (signed, -1..1, in the model's direction)
        and motor speeds (rad/s, relative to the stator)."""
        if not self.r:
            return self.v_oc
        num, den = self.v_oc, 1.0
        for d, w, kr, ir in zip(fractions, speeds, self.ke_ra, self.inv_ra):
            num += self.r * d * kr * w
            den += self.r * d * d * ir
        return num / den

    def source(self, duty):
        """What one motor driven at this duty fraction sees, the other motors idle: a source of
        duty x (V_oc - r idle_a) volts behind r duty^2 ohms more than its own Ra (Thevenin)."""
        return duty * self.v_oc, self.r * duty * duty

    def reading(self, volts):
        if self.quantum:
            return math.floor(volts / self.quantum + 1e-9) * self.quantum
        return volts
