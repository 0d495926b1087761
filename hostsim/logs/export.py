"""A robot log in a common format: CSV for spreadsheets and notebooks.

    python -m hostsim export LOG --csv [--out FILE]

writes FILE (default: the log's name with .csv, next to it) with one header row and one row per
tick, and FILE's name with .header.json beside it (the log's header: gains, configuration,
calibration, why it stopped). Every column name carries its unit (``y_th1_rad``,
``u_r_V``, ``duty_r_pct``, ``enc_r_count``; names that end in theirs stay: ``time_s``,
``battery_v``), so ``pandas.read_csv(FILE)`` needs no options. Any kind of log (balance runs,
motor identification) exports: the columns are the log's own (docs/log-format.md).
Exit status 0, or 2 with a one-line message when the log cannot be read.
"""
import argparse
import csv
import json
import os
import sys

from hostsim.errors import TipbotError
from hostsim.logs import read_log

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


def export_csv(log_path, out=None):
    """-> (csv path, header path) written for the log at log_path."""
    header, rows, names = read_log(log_path, ExportError)
    units = [c.get("unit", "") if isinstance(c, dict) else "" for c in header.get("columns", [])]
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
    ap = argparse.ArgumentParser(prog="python -m hostsim export", description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", metavar="LOG", help="a tipbot log (run or identify)")
    ap.add_argument("--csv", action="store_true", required=True, help="write CSV (the one format so far)")
    ap.add_argument("--out", metavar="FILE", help="the CSV file (default: LOG with .csv)")
    a = ap.parse_args(argv)
    try:
        csv_path, header_path = export_csv(a.log, a.out)
    except ExportError as e:
        sys.stderr.write("export: error: %s\n" % e)
        return 2
    print("export: %s (and its header, %s)" % (csv_path, header_path))
    return 0
