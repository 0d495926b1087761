"""Replay a log through the same Core the robot ran: the raw readings and battery voltages of
the log go in, the rows that come out must equal the logged ones (time columns excepted).

Bit-exact on the machine that wrote the log; across machines the matrix product's summation
order may differ in the last bits (see docs/log-format.md).
"""
import numpy as np

from tipbot_fw import logfile
from tipbot_fw.core import Core


def core_from_header(header, gains, check_gains=True):
    """A Core configured exactly as the logged run.

    check_gains: refuse gains other than the logged ones (False: replay the readings through
    other gains, to see what they would have commanded).
    """
    if check_gains and header['gains']['sha256'] != gains.sha256:
        raise ValueError('gains {} (sha256 {}) are not the ones of the log (sha256 {})'.format(
            gains.path, gains.sha256, header['gains']['sha256']))
    return Core(gains, header['config'], header['calibration']['gyro_bias_dps'],
                header['counts_per_rot'])


def replay(header, rows, gains, check_gains=True):
    """-> recomputed rows (same shape as rows; time columns copied from the log).

    From tick 0 (Core.start) if the log kept it, else restarted from the first kept row (which
    is then copied, not recomputed).
    """
    core = core_from_header(header, gains, check_gains)
    out = np.array(rows, dtype=float)
    one = logfile.LogBuffer(1)
    overrun = logfile.FLAG_BITS['overrun']
    for i in range(len(rows)):
        enc, gyro, battery_v = _readings(rows[i])
        if battery_v != core.battery_v:
            core.set_battery(battery_v)
        if i > 0:
            core.step(enc, gyro, one.data, 0)
        elif header['first_tick'] == 0:
            core.start(enc, gyro, one.data, 0)
        else:
            core.restore(rows[0], header['encoder_offsets'])
            continue
        out[i, 2:] = logfile.to_file_layout(one.mem, core.polarity)[0, 2:]
        # the overrun flag is the loop's, not the core's
        out[i, logfile.FLAGS] = int(out[i, logfile.FLAGS]) | (int(rows[i, logfile.FLAGS]) & overrun)
    return out


def _readings(r):
    """A log row's raw readings as the device gave them (ints) and its battery voltage."""
    r = r.tolist()
    e, g = logfile.ENC, logfile.GYRO
    return (tuple(int(v) for v in r[e:e + 4]), (int(r[g]), int(r[g + 1])), r[logfile.BATTERY])
