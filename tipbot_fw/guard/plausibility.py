"""What the EV3's hardware can report, so that a reading beyond it is a failed read, not data.

Battery. The EV3 runs on 6 AA cells or its 7.4 V (2S) Li-ion pack. The highest voltage either
can give is 6 fresh lithium primary AA cells, 1.8 V each: 10.8 V (alkaline: 6 x 1.6 = 9.6 V;
the pack: 8.4 V full). The lowest the brick runs on is its battery driver's voltage_min_design,
4.8 V (the pack itself shuts the brick down at 6.0 V, lms2012; ../shared/ev3-hardware.md). So a
voltage_now outside [BATTERY_MIN_V, BATTERY_MAX_V] = [4.5, 11.0] V is no battery's: the run
stops (tipbot_fw.guard.safety.ImplausibleBattery) and the value is never divided by. Between two
readings (about a second apart) a battery's open-circuit voltage moves by far less than a volt;
what moves it is the sag under the motors' current, I x R: 4 motors at 7.6 V into 6-7 ohm
windings draw at most about 4.5 A, and 6 AA cells have about 0.6 ohm: 2.7 V. A step beyond
BATTERY_MAX_STEP_V (3 V) is therefore a failed reading.

Gyro. GYRO-G&A reports its rate within +-440 deg/s (lego-ev3-gyro, ev3_uart_sensor_defs.c):
beyond that the value is not a reading.

Encoders. No-load speed at 9 V: Large 175 rpm (1050 deg/s), Medium 260 rpm (1560 deg/s), NXT
170 rpm (1020 deg/s) (ev3dev's max_speed, pybricks motor data). The speed scales with the
voltage (at most BATTERY_MAX_V), and a motor can be back-driven faster than it drives itself
(a falling link, a wheel rolling downhill): BACKDRIVE_MARGIN 2 on top. Two reads of ``position``
are dt apart and each may be up to ENCODER_UPDATE_S (2 ms: the counts are updated at 500 Hz)
old, so a motor turns at most speed x (dt + 2 ms) + 1 count between them. At 5 ms that is 19
counts for a Large motor, 27 for a Medium one; more is a failed read. A control core that
computes in fixed point takes a count change up to its max_count_step (the Kalman core: 1023,
tipbot_fw.cores.kalman): the bound is capped there (EncoderBound.with_max_step, applied by the loop),
which only a tick about 0.3 s late could reach, so that no reading the loop lets through can
overflow the core's integers.
"""
import copy

from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.guard.safety import DeviceFailure, ImplausibleBattery

BATTERY_MIN_V = 4.5
BATTERY_MAX_V = 11.0
BATTERY_MAX_STEP_V = 3.0
GYRO_MAX_DPS = 440
NO_LOAD_DPS_AT_9V = {'lego-ev3-l-motor': 1050.0, 'lego-ev3-m-motor': 1560.0, 'lego-nxt-motor': 1020.0}
FASTEST_DPS_AT_9V = max(NO_LOAD_DPS_AT_9V.values())
BACKDRIVE_MARGIN = 2.0
ENCODER_UPDATE_S = 0.002


def check_battery(volts, previous=None, when='at start'):
    """volts if an EV3 battery can read that (and, after `previous`, step there); else
    ImplausibleBattery naming the reading."""
    if not BATTERY_MIN_V <= volts <= BATTERY_MAX_V:     # also False for NaN
        raise ImplausibleBattery(
            'implausible battery reading {}: {!r} V is outside what an EV3 runs on ({}-{} V): a failed '
            'read'.format(when, volts, BATTERY_MIN_V, BATTERY_MAX_V))
    if previous is not None and abs(volts - previous) > BATTERY_MAX_STEP_V:
        raise ImplausibleBattery(
            'implausible battery reading {}: {:.3f} V after {:.3f} V, a step beyond the {} V a battery\'s sag '
            'can explain: a failed read'.format(when, volts, previous, BATTERY_MAX_STEP_V))
    return volts


def motor_speed_dps(config, role):
    """Fastest plausible turn of a motor (deg/s): its no-load speed at the highest battery
    voltage, times the back-driving margin."""
    no_load = NO_LOAD_DPS_AT_9V.get(config['drivers'][role], FASTEST_DPS_AT_9V)
    return no_load * BATTERY_MAX_V / 9.0 * BACKDRIVE_MARGIN


class EncoderBound(object):
    """The encoder check of the control loop: ``counts_per_s`` (4, motor order) and ``per_tick``,
    the one bound the loop compares all four jumps with at the nominal period (the largest of
    the four: one constant keeps the tick's check to a few comparisons); check() is the exact,
    per-motor test the loop falls back on when that fails (a late tick moved them further)."""

    def __init__(self, config, counts_per_rot, period_s):
        if config is None:      # no encoder bound (only the gyro's)
            self.counts_per_s = [float('inf')] * 4
            self.ports = ['?'] * 4
        else:
            self.counts_per_s = [motor_speed_dps(config, r) * c / 360.0 for r, c in zip(MOTOR_ROLES, counts_per_rot)]
            self.ports = [config['ports'][r] for r in MOTOR_ROLES]
        self.max_step = float('inf')
        self.period_s = period_s
        self.per_tick = max(self.bound(i, period_s) for i in range(4))

    def with_max_step(self, max_step):
        """This bound, capped at max_step counts whatever the time between two reads (None:
        itself): what a fixed-point core can take."""
        if max_step is None or max_step >= self.max_step:
            return self
        capped = copy.copy(self)
        capped.max_step = max_step
        capped.per_tick = max(capped.bound(i, self.period_s) for i in range(4))
        return capped

    def bound(self, i, dt_s):
        reach = self.counts_per_s[i] * (dt_s + ENCODER_UPDATE_S) + 1.0
        return reach if reach < self.max_step else self.max_step

    def check(self, previous, enc, dt_s, gyro_rate, tick):
        """DeviceFailure if a reading is beyond the hardware (the loop's fast check failed)."""
        if not -GYRO_MAX_DPS <= gyro_rate <= GYRO_MAX_DPS:
            raise DeviceFailure('implausible reading at tick {}: gyro rate {!r} deg/s beyond the sensor\'s '
                                '+-{} deg/s: a failed read'.format(tick, gyro_rate, GYRO_MAX_DPS))
        for i in range(4):
            jump = enc[i] - previous[i]
            bound = self.bound(i, dt_s)
            if not -bound <= jump <= bound:
                why = 'more than the motor can turn' if bound < self.max_step else \
                    'more than the control law\'s fixed-point range takes'
                raise DeviceFailure(
                    'implausible reading at tick {}: the encoder of {} ({}) moved {} counts in {:.1f} ms, {} '
                    '({:.0f}): a failed read'.format(tick, MOTOR_ROLES[i], self.ports[i], jump, 1e3 * dt_s, why, bound))
