"""Gyro bias at start: average the rate over a still window, refuse if the robot moved."""
from tipbot_fw.safety import CalibrationError, DeviceFailure


class GyroCalibration(object):
    def __init__(self, gyro_bias_dps, rate_min_dps, rate_max_dps, angle_change_deg, samples, period_s):
        self.gyro_bias_dps = gyro_bias_dps
        self.rate_min_dps = rate_min_dps
        self.rate_max_dps = rate_max_dps
        self.angle_change_deg = angle_change_deg
        self.samples = samples
        self.period_s = period_s

    def as_dict(self):
        return dict(self.__dict__)


def measure_gyro(devices, clock, period_s, duration_s):
    """Sample the gyro every period_s for duration_s -> GyroCalibration (no verdict)."""
    n = max(2, int(round(duration_s / period_s)))
    rates = []
    angles = []
    deadline = clock.now()
    for _ in range(n):
        clock.sleep_until(deadline)
        try:
            _, (angle, rate) = devices.read_raw()
        except (OSError, ValueError) as e:
            raise DeviceFailure('gyro read failed during calibration: {}'.format(e))
        rates.append(rate)
        angles.append(angle)
        deadline += period_s
    return GyroCalibration(float(sum(rates)) / n, min(rates), max(rates),
                           angles[-1] - angles[0], n, period_s)


def calibrate_gyro(devices, clock, period_s, cal_config):
    """Bias from a still window; CalibrationError if the rate spread or the sensor's angle
    change exceeds gyro_calibration.max_rate_spread_dps / max_angle_change_deg."""
    cal = measure_gyro(devices, clock, period_s, cal_config['duration_s'])
    spread = cal.rate_max_dps - cal.rate_min_dps
    if spread > cal_config['max_rate_spread_dps']:
        raise CalibrationError(
            'gyro rate varied by {} deg/s during calibration (gyro_calibration.max_rate_spread_dps'
            ' is {}): keep the robot still and try again'.format(spread, cal_config['max_rate_spread_dps']))
    if abs(cal.angle_change_deg) > cal_config['max_angle_change_deg']:
        raise CalibrationError(
            'gyro angle changed by {} deg during calibration (gyro_calibration.max_angle_change_deg'
            ' is {}): keep the robot still and try again'.format(cal.angle_change_deg, cal_config['max_angle_change_deg']))
    return cal
