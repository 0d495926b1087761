"""Gyro bias at start: average the rate over a still window, refuse if the robot moved.

A still gyro still drifts: its angle moves by its bias times the window (1-2 deg/s is common),
so the angle change is judged against the drift that the measured mean rate explains, not
against zero. The samples of the first ``settle_s`` are read but not used: after the mode
switch to GYRO-G&A (tipbot_fw.io.ev3dev, at start-up) the first samples may still be the
previous mode's, an angle counted since the sensor was plugged in and no rate.

What the window cannot tell apart: a bias from a steady turn. A held robot does not turn
steadily, so a mean rate beyond ``max_bias_dps`` is taken for a turn (or a gyro too poor to
balance with); any other movement changes the rate (``max_rate_spread_dps``) or moves the
angle more than the rate explains (``max_angle_change_deg``: a knock between two samples).
"""
from tipbot_fw.guard.safety import CalibrationError, DeviceFailure


class GyroCalibration(object):
    def __init__(self, gyro_bias_dps, rate_min_dps, rate_max_dps, angle_change_deg, samples, period_s,
                 settle_samples, window_s):
        self.gyro_bias_dps = gyro_bias_dps
        self.rate_min_dps = rate_min_dps
        self.rate_max_dps = rate_max_dps
        self.angle_change_deg = angle_change_deg
        self.samples = samples
        self.period_s = period_s
        self.settle_samples = settle_samples
        self.window_s = window_s
        # what the bias does not explain: the robot moved (or a sample was stale)
        self.unexplained_angle_deg = angle_change_deg - gyro_bias_dps * window_s

    def as_dict(self):
        return dict(self.__dict__)


def sample_counts(cal_config, period_s):
    """-> (samples read and not used, samples used) of a calibration at period_s."""
    return (int(round(cal_config['settle_s'] / period_s)),
            max(2, int(round(cal_config['duration_s'] / period_s))))


def window_s(cal_config, period_s):
    """Seconds from the calibration's first sample to its last, as it schedules them (the
    session records when it ended; the host's simulated hand holds the robot this long)."""
    settle, n = sample_counts(cal_config, period_s)
    return (settle + n - 1) * period_s


def measure_gyro(devices, clock, period_s, cal_config):
    """Sample the gyro every period_s: settle_s unused, then duration_s -> GyroCalibration
    (no verdict)."""
    settle, n = sample_counts(cal_config, period_s)
    rates = []
    angles = []
    times = []
    deadline = clock.now()
    for i in range(settle + n):
        clock.sleep_until(deadline)
        try:
            _, (angle, rate) = devices.read_raw()
        except (OSError, ValueError) as e:
            raise DeviceFailure('gyro read failed during calibration: {}'.format(e))
        if i >= settle:
            times.append(clock.now())
            rates.append(rate)
            angles.append(angle)
        deadline += period_s
    return GyroCalibration(float(sum(rates)) / n, min(rates), max(rates), angles[-1] - angles[0], n, period_s,
                           settle, times[-1] - times[0])


def calibrate_gyro(devices, clock, period_s, cal_config):
    """Bias from a still window; CalibrationError if the rate spread, the mean rate or the
    angle change the mean rate does not explain exceeds gyro_calibration.max_rate_spread_dps,
    max_bias_dps or max_angle_change_deg."""
    cal = measure_gyro(devices, clock, period_s, cal_config)
    spread = cal.rate_max_dps - cal.rate_min_dps
    if spread > cal_config['max_rate_spread_dps']:
        raise CalibrationError(
            'gyro rate varied by {} deg/s during calibration (gyro_calibration.max_rate_spread_dps'
            ' is {}): keep the robot still and try again'.format(spread, cal_config['max_rate_spread_dps']))
    if abs(cal.gyro_bias_dps) > cal_config['max_bias_dps']:
        raise CalibrationError(
            'gyro read a steady {:.1f} deg/s during calibration (gyro_calibration.max_bias_dps is {}): '
            'the robot was turning, or the gyro drifts too much to balance with: keep the robot still and '
            'try again'.format(cal.gyro_bias_dps, cal_config['max_bias_dps']))
    if abs(cal.unexplained_angle_deg) > cal_config['max_angle_change_deg']:
        raise CalibrationError(
            'gyro angle changed by {} deg during calibration where its drift of {:.2f} deg/s explains {:.1f} deg'
            ' (gyro_calibration.max_angle_change_deg is {} beyond that): keep the robot still and try again'.format(
                cal.angle_change_deg, cal.gyro_bias_dps, cal.gyro_bias_dps * cal.window_s,
                cal_config['max_angle_change_deg']))
    return cal
