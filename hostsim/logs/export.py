"""A robot log in a common format: CSV for spreadsheets and notebooks.

    python -m hostsim export LOG [--csv] [--out FILE] [--gains FILE]

writes FILE (default: the log's name with .csv, next to it) with one header row and one row per
tick, and FILE's name with .header.json beside it (the log's header: gains, configuration,
calibration, why it stopped). Every column name carries its unit (``y_th1_rad``,
``u_r_V``, ``duty_r_pct``, ``enc_r_count``; names that end in theirs stay: ``time_s``,
``battery_v``), so ``pandas.read_csv(FILE)`` needs no options. Any kind of log (balance runs,
motor identification) exports: the columns are the log's own (docs/log-format.md). A balance
run of the Kalman core, whose rows hold raw readings and the filter's carried state, gets the
physical columns of the detector's logs after its own, rebuilt as the replay rebuilds them
(tipbot_fw.record.replay.signals, with the gains the run used, found as `hostsim replay` finds them,
or --gains): the estimate ``xt_*`` (x^), the disturbance estimate ``w_*``, the applied inputs
``u_*``, the law's output before rounding and saturation ``u_cmd_*`` and the filter's gyro bias
``gyro_bias`` (deg/s, as the sensor reads). Exit status 0, or 2 with a one-line message when
the log (or the gains of a Kalman log) cannot be read.
"""
import argparse
import csv
import json
import os
import sys

import hostsim
import numpy as np

from hostsim.errors import TipbotError
from hostsim.logs import read_log
from tipbot_fw.record import replay as fw_replay
from tipbot_fw.gains import GainsError, load_gains
from tipbot_fw.vocabulary import ACTUATED_INPUTS
from tipbot_fw import vocabulary

# unit -> what a column name gets appended (None: nothing)
UNIT_SUFFIX = {"m/s": "m_per_s", "rad/s": "rad_per_s", "deg/s": "deg_per_s", "%": "pct", "bits": None, "": None}


class ExportError(TipbotError):
    """The log cannot be exported; the message names it and why."""


def column_name(name, unit):
    """A pandas-friendly column name: the log's name with its unit, unless it ends in it."""
    suffix = UNIT_SUFFIX.get(unit, unit)
    if not suffix or name.lower().endswith("_" + suffix.lower()):
        return name
    return "%s_%s" % (name, suffix)


def csv_header(columns):
    """Column names for [(name, unit)]."""
    return [column_name(n, u) for n, u in columns]


def write_csv(path, columns, rows):
    """rows: an iterable of sequences of numbers; integral floats are written as integers."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(csv_header(columns))
        for row in rows:
            w.writerow([format_value(v) for v in row])


def format_value(v):
    v = float(v)
    return "%d" % v if v.is_integer() and abs(v) < 2 ** 53 else repr(v)


# The physical columns a Kalman log gets (the detector's file columns of the same names), of the
# four motors' inputs (link 1 has none: its columns would always read 0)
MOTOR_INPUTS = [n for i, n in enumerate(vocabulary.INPUTS) if i in ACTUATED_INPUTS]
PHYSICAL = ([("xt_" + n, u) for n, u in zip(vocabulary.STATE_NAMES, vocabulary.STATE_UNITS)]
            + [(p + n, "V") for p in ("w_", "u_", "u_cmd_") for n in MOTOR_INPUTS] + [("gyro_bias", "deg/s")])


def physical_columns(log_path, header, rows, gains_path=None):
    """-> (columns, values) the export adds to a Kalman log: PHYSICAL from the replay's signals()."""
    from hostsim.logs.replay import find_logged_gains
    try:
        path = find_logged_gains(log_path, header, [gains_path] if gains_path else ())
    except (KeyError, TypeError) as e:
        raise ExportError("%s: its header names no gains (%s)" % (log_path, e))
    if path is None:
        raise ExportError("%s: a Kalman log's physical columns need the gains it ran (sha256 %s...): put them next to "
                          "it as gains-<sha256>.json (make logs does) or give --gains FILE"
                          % (log_path, str(header["gains"]["sha256"])[:16]))
    try:
        sig = fw_replay.signals(header, rows, load_gains(path))
        bias_dps = sig.gyro_bias * (180.0 / np.pi) * header["config"]["gyro_sign"]
    except GainsError as e:
        raise ExportError(str(e))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ExportError("%s: a header this version cannot interpret: %s: %s" % (log_path, type(e).__name__, e))
    act = list(ACTUATED_INPUTS)
    return PHYSICAL, np.hstack([sig.x_hat, sig.w_hat[:, act], sig.u[:, act], sig.u_cmd[:, act],
                                bias_dps[:, None]])


def export_csv(log_path, out=None, gains_path=None):
    """-> (csv path, header path) written for the log at log_path."""
    header, rows, names = read_log(log_path, ExportError)
    units = [c.get("unit", "") if isinstance(c, dict) else "" for c in header.get("columns", [])]
    if header.get("kind", "run") == "run" and header.get("estimator") == "kalman":
        extra, values = physical_columns(log_path, header, rows, gains_path)
        names, units, rows = names + [n for n, _ in extra], units + [u for _, u in extra], np.hstack([rows, values])
    stem = os.path.splitext(out or log_path)[0]
    csv_path = out or stem + ".csv"
    header_path = stem + ".header.json"
    try:
        write_csv(csv_path, list(zip(names, units)), rows)
        with open(header_path, "w") as f:
            json.dump(header, f, indent=1, sort_keys=True)
    except OSError as e:
        raise ExportError("%s: cannot write: %s" % (e.filename or csv_path, e.strerror or e))
    return csv_path, header_path


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("export"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", metavar="LOG", help="a tipbot log (run or identify)")
    ap.add_argument("--csv", action="store_true", help="write CSV (the default and the one format so far)")
    ap.add_argument("--out", metavar="FILE", help="the CSV file (default: LOG with .csv)")
    ap.add_argument("--gains", metavar="FILE", help="the gains a Kalman log ran (default: found by its sha256)")
    a = ap.parse_args(argv)
    try:
        csv_path, header_path = export_csv(a.log, a.out, a.gains)
    except ExportError as e:
        sys.stderr.write("export: error: %s\n" % e)
        return 2
    print("export: %s (and its header, %s)" % (csv_path, header_path))
    return 0
