"""The tick core: raw readings + battery voltage -> duties and a log row. No I/O, no time.

The loop on the brick and a replay on the host call the very same methods with the same
numbers, so a replay of a log reproduces the robot's computation. Two cores, chosen by the
configuration's `estimator`:

- `kalman` (the default): tipbot_fw.cores.kalman.KalmanCore, the steady-state Kalman filter and the
  LQR law in fixed point (the gains file's `kalman` block);
- `detector`: tipbot_fw.cores.detector_core.DetectorCore, the paper's signal chain, Section 6 robust
  detector and law, for reproducing the paper.

Both offer: set_gyro_bias(bias_dps) after the calibration; set_battery(battery_v) before the
first tick and whenever the reading changes (outside the ticks); start(enc, gyro, buf, offset)
for the first tick and step(...) for every later one, which write the tick's memory row (all
but its two time columns) into buf at byte offset `offset` and return (duties, stop);
skip(periods) after a tick the loop was late from, with the whole periods it missed (the
Kalman core predicts through them with the duties held; a replay calls it from the log's
flags); wind_down() once a second outside the ticks (the Kalman core keeps its law's integrators
within their limit; True if it changed them, which the log's flags record for the replay); restore(file_row, encoder_offsets) to continue from a logged row; `rows`, the row layout
(tipbot_fw.record.logfile: DetectorRows or KalmanRows), which row_layout() gives before the core is
made (the log's header is written before the calibration); angles(mem_row) for a stop message;
header() for the log; limits; battery_v; max_count_step, the largest change of a wheel's count
from tick to tick the core takes (None: any), which the loop's plausibility check enforces.
"""
import importlib

# imported when selected: a run keeps the modules of its own core only (memory on the brick)
CORES = {'kalman': ('tipbot_fw.cores.kalman', 'KalmanCore'), 'detector': ('tipbot_fw.cores.detector_core', 'DetectorCore')}


def core_class(estimator):
    module, name = CORES[estimator]
    return getattr(importlib.import_module(module), name)


def make_core(gains, config, counts_per_rot=(360, 360, 360, 360), layout=None):
    """The core the configuration selects, for these gains (layout: its row_layout(), to share
    the one the log was opened with)."""
    return core_class(config['estimator'])(gains, config, counts_per_rot, layout)


def row_layout(gains, config):
    """The log row of the core the configuration selects (tipbot_fw.record.logfile)."""
    return core_class(config['estimator']).row_layout(gains, config)
