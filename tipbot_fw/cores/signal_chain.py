"""Signal chain: raw encoder counts and gyro readings -> the measured state y (10, SI).

Scalar Python on purpose: at 4 encoders and one gyro, a handful of float operations costs far
less than a numpy call on the brick (no FPU, every numpy call has a fixed overhead).

Choices (why):
- th1 integrates the bias-corrected gyro RATE (Euler, th1 += ts * rate). The sensor's own angle is
  an integer degree (0.017 rad, as large as the whole balancing motion) and is integrated by
  the sensor from the same rate with no bias correction, so it drifts just as much; it is only
  logged and used to detect motion during calibration.
- The bias is measured at start with the robot still (calibration), and by default that value
  is kept for the whole run (gyro_bias_time_constant_s = null). Tracking it while balancing
  cannot work without an absolute tilt reference, which the EV3 gyro lacks: a small bias error
  makes the controller hold the *estimated* th1 at zero, so the true th1 drifts; a tracker
  that takes the mean measured rate as the bias then learns that drift as bias, which grows
  the error further (a positive feedback loop). In the firmware-in-the-loop Section 8 run
  (bias 1 deg/s, noise 0.3 deg/s) a 60 s tracker walked the bias from 0.99 to 0.89 deg/s in
  50 s and the robot ended 0.42 m from its origin, bent 0.07 / 0.12 rad at the joints;
  without tracking it ended 0.04 m away, within 0.011 rad of upright.
  The tracker remains available for long runs with a drifting gyro (a slow first-order
  low-pass of the raw rate, time constant tau); only quiet samples feed it (|rate - bias| <
  gyro_bias_quiet_dps), so a real rotation (a tilted start, a push) is not learnt as bias.
- Wheel encoders measure the wheel relative to link 1, so d = R_w * (phi_rel + th1).
- Positions are not filtered (encoders are exact to one count and lag costs stability);
  rates are differentiated positions through a first-order low-pass (filtered
  differentiation), th1_dot is the low-passed gyro rate. Low-pass: f += a (x - f) with
  a = 1 - exp(-2 pi fc ts), i.e. the exact discretization of a first-order lag at the period.
- Everything carried from tick to tick is in a log row (y, the raw readings, the bias used), so
  a replay can restart the chain at any logged tick (restore()).
"""
import math

from tipbot_fw.config import motor_polarity


def lowpass_coefficient(cutoff_hz, ts_s):
    return 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * ts_s)


class SignalChain(object):
    """Raw readings -> y = [d_r, d_l, th1, th2, th3, d_r_dot, d_l_dot, th1_dot, th2_dot, th3_dot].

    start() sets the encoder zeros from the first reading; update() for every later tick.
    Attributes after a tick: y (the list returned), bias_used_dps (subtracted in that tick),
    bias_dps (for the next tick).
    """

    def __init__(self, config, ts_s, gyro_bias_dps, counts_per_rot=(360, 360, 360, 360)):
        polarity = motor_polarity(config)
        rad_per_count = [polarity[i] * 2.0 * math.pi / counts_per_rot[i] for i in range(4)]
        r_w = float(config['wheel_radius_m'])
        f = config['filters']
        a_enc = lowpass_coefficient(f['encoder_rate_cutoff_hz'], ts_s)
        a_gyro = lowpass_coefficient(f['gyro_rate_cutoff_hz'], ts_s)
        tau = config['gyro_bias_time_constant_s']
        a_bias = 0.0 if tau is None else lowpass_coefficient(1.0 / (2.0 * math.pi * tau), ts_s)
        self.quiet_dps = float(config['gyro_bias_quiet_dps'])
        pose = config['start_pose_rad']
        self.th1_0 = float(pose['th1'])
        # One tuple, unpacked into locals in update(): attribute lookups cost on the brick.
        # Filtered differentiation v += a ((p - p_prev) / ts - v) is computed as
        # v = (1 - a) v + (a / ts) (p - p_prev); the gyro factors deg -> rad, sign and ts are
        # folded into the coefficients of the bias-corrected raw rate.
        gyro_rad = config['gyro_sign'] * math.pi / 180.0
        self.c = (r_w * rad_per_count[0], r_w * rad_per_count[1],   # m per count, wheels
                  rad_per_count[2], rad_per_count[3],                # rad per count, joints
                  r_w, a_bias, gyro_rad * ts_s, 1.0 - a_gyro, a_gyro * gyro_rad,
                  1.0 - a_enc, a_enc / ts_s, float(pose['th2']), float(pose['th3']))
        self.bias_dps = float(gyro_bias_dps)
        self.bias_used_dps = self.bias_dps
        self.offsets = None
        self.y = None

    def start(self, enc, gyro):
        """First tick: the current counts are the zeros of the start pose; rates start at 0."""
        self.offsets = (enc[0], enc[1], enc[2], enc[3])
        th1 = self.th1_0
        r_w = self.c[4]
        self._track_bias(gyro[1])
        self.y = [r_w * th1, r_w * th1, th1, self.c[11], self.c[12], 0.0, 0.0, 0.0, 0.0, 0.0]
        return self.y

    def _track_bias(self, rate_dps):
        b = self.bias_dps
        self.bias_used_dps = b
        e = rate_dps - b
        if -self.quiet_dps < e < self.quiet_dps:
            self.bias_dps = b + self.c[5] * e

    def update(self, enc, gyro):
        """One tick -> y (a new list)."""
        k_r, k_l, k_2, k_3, r_w, a_b, g_th, c_g, g_w, c_e, g_e, th2_0, th3_0 = self.c
        o_r, o_l, o_2, o_3 = self.offsets
        d_r_p, d_l_p, th1, th2_p, th3_p, v_r, v_l, w_1, w_2, w_3 = self.y   # previous tick
        b = self.bias_dps
        e = gyro[1] - b                 # bias-corrected raw rate, deg/s
        self.bias_used_dps = b
        if -self.quiet_dps < e < self.quiet_dps:
            self.bias_dps = b + a_b * e     # slow bias tracking of quiet samples (module docstring)
        th1 += g_th * e
        r_th1 = r_w * th1
        d_r = k_r * (enc[0] - o_r) + r_th1
        d_l = k_l * (enc[1] - o_l) + r_th1
        th2 = k_2 * (enc[2] - o_2) + th2_0
        th3 = k_3 * (enc[3] - o_3) + th3_0
        y = [d_r, d_l, th1, th2, th3,
             c_e * v_r + g_e * (d_r - d_r_p), c_e * v_l + g_e * (d_l - d_l_p),
             c_g * w_1 + g_w * e,
             c_e * w_2 + g_e * (th2 - th2_p), c_e * w_3 + g_e * (th3 - th3_p)]
        self.y = y
        return y

    def restore(self, offsets, y, bias_used_dps, rate_dps):
        """State as right after a tick whose outputs were logged (for replay from any row)."""
        self.offsets = tuple(offsets)
        self.y = list(y)
        self.bias_dps = float(bias_used_dps)
        self._track_bias(rate_dps)
