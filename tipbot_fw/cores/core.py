"""The tick core: raw readings + battery voltage -> duties and a log row. No I/O, no time.

The loop on the brick and a replay on the host call the very same methods with the same
numbers, so a replay of a log reproduces the robot's computation. Core is the interface every
core implements; make_core picks the one the configuration's `estimator` names:

- `kalman` (the default): tipbot_fw.cores.kalman.KalmanCore, the steady-state Kalman filter and
  the LQR law in fixed point (the gains file's `kalman` block);
- `detector`: tipbot_fw.cores.detector_core.DetectorCore, the paper's signal chain, Section 6
  robust detector and law, for reproducing the paper.

Each core declares its log row (row_layout: tipbot_fw.cores.kalman_rows.KalmanRows,
tipbot_fw.cores.detector_rows.DetectorRows), which the log's header describes, so a reader
needs nothing else.
"""
import importlib


class Core(object):
    """What the loop, the session and the replay ask of a core.

    Made as Core(gains, config, counts_per_rot, layout) (layout: the row_layout() the log was
    opened with, to share it). Attributes: `estimator` (the configuration's name of it), `rows`
    (its row layout), `limits` ((th1, th2, th3) stop limits, rad), `battery_v` (the reading the
    duties are scaled for), `max_count_step` (the largest change of a wheel's count from tick to
    tick the core takes, None: any; the loop's plausibility check enforces it).
    """
    estimator = None
    max_count_step = None

    @staticmethod
    def row_layout(gains, config):
        """The core's log row for these gains, before the core is made (the log's header is
        written before the calibration)."""
        raise NotImplementedError

    def set_gyro_bias(self, gyro_bias_dps):
        """The calibrated gyro bias (deg/s, the sensor's frame), before the first tick."""
        raise NotImplementedError

    def set_battery(self, battery_v):
        """Scale the law for this battery reading: before the first tick and whenever the
        reading changes, outside the ticks."""
        raise NotImplementedError

    def start(self, enc, gyro, buf, offset):
        """The first tick: (enc (4 counts), gyro (angle, rate)) -> (duties, stop), the tick's
        memory row (all but its two time slots) written into the bytearray buf at byte offset
        `offset`; stop nonzero (the fall or joint-limit flag) if the motors must stop now."""
        raise NotImplementedError

    def step(self, enc, gyro, buf, offset):
        """Every later tick, as start()."""
        raise NotImplementedError

    def skip(self, periods):
        """The loop was late by `periods` whole periods after this tick (a stall): predict
        through them, outside the tick (a replay calls it from the log's flags)."""
        raise NotImplementedError

    def live_short(self):
        """Whether a live drive plan's rows ran down to the few a stall's skip keeps (its maker,
        a side task, is then due at once: tipbot_fw.loop). A core without live plans: never."""
        return False

    def wind_down(self):
        """Once a second outside the ticks: keep the law's integrators within their limit.
        -> True if it changed them (the log's flags record it for the replay)."""
        raise NotImplementedError

    def restore(self, file_row, encoder_offsets):
        """Continue from a logged row (file layout), as right after its tick (the replay of a
        long run's kept end)."""
        raise NotImplementedError

    def angles(self, mem_row):
        """(th1, th2, th3) (rad) of a memory row, for a stop message."""
        raise NotImplementedError

    def header(self):
        """What the log's header needs to replay this core (docs/log-format.md)."""
        raise NotImplementedError

    @property
    def duties(self):
        """The last tick's duties (4 ints, before the stop)."""
        raise NotImplementedError


# imported when selected: a run keeps the modules of its own core only (memory on the brick)
CORES = {'kalman': ('tipbot_fw.cores.kalman', 'KalmanCore'),
         'detector': ('tipbot_fw.cores.detector_core', 'DetectorCore')}


def core_class(estimator):
    module, name = CORES[estimator]
    return getattr(importlib.import_module(module), name)


def make_core(gains, config, counts_per_rot=(360, 360, 360, 360), layout=None):
    """The core the configuration selects, for these gains (layout: its row_layout(), to share
    the one the log was opened with)."""
    return core_class(config['estimator'])(gains, config, counts_per_rot, layout)


def row_layout(gains, config):
    """The log row of the core the configuration selects."""
    return core_class(config['estimator']).row_layout(gains, config)
