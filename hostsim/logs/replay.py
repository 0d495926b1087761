"""Replay a run log on the host: the firmware's own signal chain, detector and controller.

    python -m hostsim replay LOG [--gains FILE] [--logged-gains FILE] [--out DIR] [--no-plots]
    (also: make replay LOG=... [GAINS=...])

The logged raw readings (encoder counts, gyro angle and rate, battery voltage) go through
tipbot_fw.record.replay, i.e. the very core the robot ran (tipbot_fw.cores.core: the Kalman filter, or the
paper's detector), and what comes out is compared with what the robot logged:

* with the gains the robot ran (found by the sha256 the log records: --logged-gains, then
  --gains, the log's directory (`make logs` fetches the brick's gains.json there as
  gains-<sha256>.json), the path in the log, gains/*.json), the replayed state (the Kalman
  filter's carried state xi, or the detector's y, x~, w^), duties and flags must equal the
  logged ones: "replays exactly" when the largest difference is <= --tol (1e-9; the Kalman
  core's integer arithmetic replays bit for bit, difference 0);
* with other gains (--gains FILE whose hash differs), the same readings show what those gains
  would have commanded (their own detector fed their own inputs; the readings stay those of
  the logged run, so this is open loop: how the robot would then have moved is a question for
  the simulator).

Plots (PNG) of logged vs replayed (and other-gains) inputs and estimates go to --out
(default out/replay/). Exit status: 0 replayed (exactly, if the logged gains were found),
1 the replay differs from the log by more than --tol, 2 the log or a gains file cannot be used
(truncated, corrupted, incompatible version, wrong gains): the message says which and why.
"""
import argparse
import glob
import hashlib
import os
import sys

import hostsim
import numpy as np

import tipbot_fw
from tipbot_fw.record import logfile
from tipbot_fw.record import replay as fw_replay
from tipbot_fw import fields
from tipbot_fw.config import ConfigError, config_from_overrides
from tipbot_fw.gains import SCALAR_BOUNDS, GainsError, load_gains
from tipbot_fw.vocabulary import ACTUATED_INPUTS
from tipbot_fw.guard.plausibility import BATTERY_MAX_V, BATTERY_MIN_V

from hostsim.errors import TipbotError
from hostsim.logs import read_log
from hostsim.paths import GAINS_DIR, out_dir
from tipbot_fw import vocabulary
from tipbot_fw.cores import kalman_rows
from tipbot_fw.cores.detector_rows import DetectorRows

DEFAULT_OUT = out_dir("replay")
DEFAULT_TOL = 1e-9
# Header fields a replay needs (docs/log-format.md); a log without them is from another version.
REQUIRED_HEADER = ("gains", "config", "calibration", "counts_per_rot", "first_tick", "ts_s", "estimator")
# The gains schema this firmware's cores read; a log recorded with another cannot be replayed here.
from tipbot_fw.vocabulary import GAINS_SCHEMA_VERSION as GAINS_SCHEMA  # noqa: E402


class ReplayError(TipbotError):
    """The log or a gains file cannot be replayed; the message says why (exit status 2)."""


# ------------------------------------------------------------------------------ the log
def load_log(path):
    """-> (header, rows, notes) of an intact, compatible log; ReplayError naming the problem.

    header["config"] is the configuration in force, completed with this version's defaults
    for fields an older firmware did not have (notes say which)."""
    header, rows, names = read_log(path, ReplayError)
    try:
        return _interpret(path, header, rows, names)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
        # a header whose fields have types this version does not expect (check_content names
        # the ones it knows): one line, not a traceback
        raise ReplayError("%s: a header this version cannot interpret: %s: %s" % (path, type(e).__name__, e))


def _interpret(path, header, rows, names):
    if header.get("kind", "run") != "run":
        raise ReplayError("%s: a log of kind %r, not a balance run: analyse it with `python -m hostsim %s`"
                          % (path, header["kind"], header["kind"]))
    written_by = header.get("versions", {}).get("tipbot_fw", "an unknown version")
    schema = header.get("gains", {}).get("schema_version") if isinstance(header.get("gains"), dict) else None
    if schema != GAINS_SCHEMA:
        raise ReplayError(
            "%s: a log of tipbot_fw %s, recorded with gains of schema %s (its control core, the paper's "
            "detector before the Kalman filter, read schema-1 gains): this tipbot_fw %s replays logs of "
            "schema-%d gains only; replay it with the tipbot version that wrote it (git history, tag of "
            "tipbot_fw %s)" % (path, written_by, schema, tipbot_fw.__version__, GAINS_SCHEMA, written_by))
    expected = expected_columns(header)
    if names != expected:
        extra = sorted(set(names) - set(expected))
        missing = sorted(set(expected) - set(names))
        detail = (["unknown: " + ", ".join(extra[:6])] if extra else []) + \
                 (["missing: " + ", ".join(missing[:6])] if missing else [])
        raise ReplayError(
            "%s: incompatible log: written by tipbot_fw %s with columns this tipbot_fw %s does not "
            "read (%s); replay it with the tipbot version that wrote it"
            % (path, written_by, tipbot_fw.__version__, "; ".join(detail) or "another column order"))
    absent = [k for k in REQUIRED_HEADER if k not in header]
    if absent or "sha256" not in header.get("gains", {}):
        raise ReplayError("%s: incompatible log: its header lacks %s (written by tipbot_fw %s, this is %s)"
                          % (path, ", ".join(absent or ["gains.sha256"]), written_by, tipbot_fw.__version__))
    if any(first > 0 for first, _ in logfile.segments(header, len(rows))) and "encoder_offsets" not in header:
        raise ReplayError("%s: incompatible log: a log without its first ticks and without encoder_offsets" % path)
    # The configuration in force: fields this version has and the log lacks (an older firmware)
    # take their defaults, which the exactness check then vouches for; fields this version does
    # not know, or values it refuses, make the log incompatible.
    try:
        config = config_from_overrides(header["config"], "%s: header.config" % path)
    except ConfigError as e:
        raise ReplayError("incompatible log: %s (written by tipbot_fw %s, this is %s)"
                          % (e, written_by, tipbot_fw.__version__))
    missing = sorted(set(_leaves(config)) - set(_leaves(header["config"])))
    notes = []
    if missing:
        notes.append("the log's configuration lacks %s (an older firmware): replayed with the default%s"
                     % (", ".join(missing), "s" if len(missing) > 1 else ""))
    header["config"] = config
    if len(rows) == 0:
        raise ReplayError("%s: the log has no ticks (the run stopped before its control loop: %s)"
                          % (path, header.get("stop_message", "see its header")))
    check_content(path, header, rows, names)
    notes += gap_notes(header)
    if header.get("incomplete"):
        notes.append("the log is incomplete: %s" % header["incomplete"])
    return header, rows, notes


def gap_notes(header):
    """What a bounded log of a long run did not keep, and how its tail is replayed."""
    notes = []
    for a, b in header.get("not_kept", []):
        notes.append("ticks %d..%d not kept (%.1f s; config log_max_rows, log_head_rows: the log holds the run's "
                     "start and its last ticks)" % (a, b, (b - a + 1) * header["ts_s"]))
    later = [first for first, _ in logfile.segments(header, 0)[1:]]
    if later:
        notes.append("replayed from each kept part's first tick (%s), re-seeded from its logged row (the core's "
                     "whole state), which is copied, not recomputed" % ", ".join(str(t) for t in later))
    if header.get("ring_dropped_chunks"):
        notes.append("%d chunk(s) of the last ticks dropped: torn by a crash or damaged" % header["ring_dropped_chunks"])
    return notes


def expected_columns(header):
    """The body columns of a run log of this firmware for the header's estimator."""
    if header.get("estimator") == "detector":
        return list(DetectorRows.column_names)
    names, units = header.get("state_names"), header.get("state_units")
    if not isinstance(names, list) or not isinstance(units, list):
        return []
    columns = [c[0] for c in kalman_rows.kalman_columns(names, units)]
    if "reference" in header:       # the drive reference (a firmware before it logged none)
        columns += [c[0] for c in kalman_rows.REFERENCE_COLUMNS]
    return columns


def check_content(path, header, rows, names):
    """What a replay takes from a log, checked (ReplayError '<log>: field <name> <problem>'): the
    header's period, gains hash, calibration and counts, and finite rows with a battery voltage
    an EV3 can read, sampled at the header's period."""
    f = fields.Fields(path, ReplayError)
    lo, hi, _, why = SCALAR_BOUNDS["ts_s"]
    ts = f.number("ts_s", header["ts_s"], lo=lo, hi=hi, lo_open=False)
    sha = header["gains"]["sha256"]
    if not isinstance(sha, str) or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        f.fail("gains.sha256", "must be the 64 hex digits of a sha256, got %r" % (sha,))
    f.check("calibration", header["calibration"], fields.obj)
    f.number("calibration.gyro_bias_dps", header["calibration"].get("gyro_bias_dps"), lo=-100, hi=100, lo_open=False)
    counts = header["counts_per_rot"]
    if not isinstance(counts, list) or len(counts) != 4 or not all(
            isinstance(c, int) and not isinstance(c, bool) and 1 <= c <= 100000 for c in counts):
        f.fail("counts_per_rot", "must be 4 positive integers, got %r" % (counts,))
    f.check("first_tick", header["first_tick"], fields.number(lo=0, lo_open=False, integer=True))
    if "segments" in header:        # a rewritten log's header: its parts must describe its rows
        seg = header["segments"]
        if not (isinstance(seg, list) and all(isinstance(p, list) and len(p) == 2 and all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in p) for p in seg)
                and sum(p[1] for p in seg) == len(rows)
                and all(a[0] + a[1] <= b[0] for a, b in zip(seg, seg[1:]))):
            f.fail("segments", "must be [first tick, rows] of each kept part, in order, %d rows in all, got %r"
                   % (len(rows), seg))
    if "encoder_offsets" in header:
        f.check("encoder_offsets", header["encoder_offsets"], fields.numbers(4))
    bad = np.argwhere(~np.isfinite(rows))
    if len(bad):
        i, c = bad[0]
        f.fail("rows[%d].%s" % (i, names[c]), "is %r, not a finite number" % rows[i, c])
    battery = rows[:, names.index("battery_v")]
    out = np.nonzero((battery < BATTERY_MIN_V) | (battery > BATTERY_MAX_V))[0]
    if len(out):
        f.fail("rows[%d].battery_v" % out[0], "is %r V, outside what an EV3 battery reads (%g-%g V)"
               % (battery[out[0]], BATTERY_MIN_V, BATTERY_MAX_V))
    if len(rows) >= 3:
        step = float(np.median(np.diff(rows[:, names.index("time_s")])))
        if not 0.5 * ts <= step <= 2.0 * ts:
            f.fail("ts_s", "is %g s, but the rows are %g s apart: the header does not describe these rows" % (ts, step))


def _leaves(doc, prefix=""):
    """Dotted paths of the leaves of a nested dict."""
    out = []
    for key, value in doc.items():
        if isinstance(value, dict):
            out += _leaves(value, prefix + key + ".")
        else:
            out.append(prefix + key)
    return out


# ------------------------------------------------------------------------------ gains
def _sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def gains_candidates(log_path, header, explicit=()):
    """Files that may hold the logged gains, in the order they are tried."""
    out = [p for p in explicit if p]
    log_dir = os.path.dirname(os.path.abspath(log_path))
    out += sorted(glob.glob(os.path.join(log_dir, "gains-*.json")))
    out += sorted(glob.glob(os.path.join(log_dir, "*.json")))
    logged_path = header.get("gains", {}).get("path")
    if logged_path:
        out.append(logged_path)
    out += sorted(glob.glob(os.path.join(GAINS_DIR, "*.json")))
    seen, unique = set(), []
    for p in out:
        key = os.path.abspath(p)
        if key not in seen and os.path.isfile(p):
            seen.add(key)
            unique.append(p)
    return unique


def find_logged_gains(log_path, header, explicit=()):
    """-> path of a file whose sha256 is the log's gains hash, or None."""
    want = header["gains"]["sha256"]
    for p in gains_candidates(log_path, header, explicit):
        try:
            if _sha256(p) == want:
                return p
        except OSError:
            continue
    return None


def _load_gains(path):
    try:
        return load_gains(path)
    except GainsError as e:
        raise ReplayError(str(e))


# ------------------------------------------------------------------------------ replay
def groups(names):
    """(label, column indices) of what the replay recomputes and compares, for a log's columns."""
    def idx(pred):
        return [i for i, n in enumerate(names) if pred(n)]
    out = [
        ("filter state xi", idx(lambda n: n.startswith("xi_"))),
        ("signal chain y", idx(lambda n: n.startswith("y_"))),
        ("estimates x~", idx(lambda n: n.startswith("xt_"))),
        ("disturbance w^", idx(lambda n: n.startswith("w_"))),
        ("inputs u", idx(lambda n: n.startswith("u_") and not n.startswith("u_cmd_"))),
        ("commanded u", idx(lambda n: n.startswith("u_cmd_"))),
        ("duties", idx(lambda n: n.startswith("duty_"))),
        ("gyro bias", idx(lambda n: n == "gyro_bias")),
        ("flags", idx(lambda n: n == "flags")),
    ]
    return [(label, cols) for label, cols in out if cols]


def max_abs_diff(a, b, cols):
    if not cols or len(a) == 0:
        return 0.0
    d = np.abs(a[:, cols] - b[:, cols])
    d[np.isnan(d)] = np.inf
    return float(np.max(d))


def replay_rows(header, rows, gains, as_logged=True):
    """Rows recomputed by the firmware's replay with ``gains``.

    as_logged=False replays with gains that are not the log's (a what-if); everything else
    (config, gyro bias, encoder zeros, start) is the log's.
    """
    try:
        return fw_replay.replay(header, rows, gains, check_gains=as_logged)
    except (KeyError, TypeError, IndexError, AttributeError) as e:
        written_by = header.get("versions", {}).get("tipbot_fw", "?")
        if written_by == tipbot_fw.__version__:
            raise ReplayError("tipbot_fw.record.replay failed on this log, although the log says it was written by "
                              "this version (%s): %s: %s. Either the log comes from a development state of "
                              "that version with another header, or this is a bug: report it with the log"
                              % (written_by, type(e).__name__, e))
        raise ReplayError("incompatible log: the replay needs %s, which this log lacks or has in another "
                          "form (written by tipbot_fw %s, this is %s)" % (e, written_by, tipbot_fw.__version__))


class Report(object):
    """What replay_log found; attributes are set by replay_log."""

    def __init__(self):
        self.log_path = None
        self.header = None
        self.rows = None
        self.logged_gains_path = None
        self.logged_gains = None
        self.names = None
        self.replayed = None        # rows replayed with the logged gains (None if not found)
        self.diffs = []             # [(label, max |replayed - logged|)]
        self.max_diff = None
        self.exact = None
        self.other_gains_path = None
        self.other = None           # rows replayed with the other gains
        self.other_gains = None
        self.other_u_diff = None    # {input: (max abs, rms)} of u_other - u_logged
        self.other_sat = None       # fraction of ticks with a saturated input
        self.plots = []
        self.notes = []


def replay_log(log_path, gains_path=None, logged_gains_path=None, tol=DEFAULT_TOL):
    """Replay a log; -> Report. ReplayError for logs and gains that cannot be used."""
    r = Report()
    r.log_path = log_path
    header, rows, r.notes = load_log(log_path)
    r.header, r.rows = header, rows
    r.names = [c["name"] for c in header["columns"]]
    if logged_gains_path and not os.path.isfile(logged_gains_path):
        raise ReplayError("--logged-gains %s: no such file" % logged_gains_path)
    if logged_gains_path and _sha256(logged_gains_path) != header["gains"]["sha256"]:
        raise ReplayError("--logged-gains %s (sha256 %s) is not the gains file of the log (sha256 %s)"
                          % (logged_gains_path, _sha256(logged_gains_path)[:16], header["gains"]["sha256"][:16]))
    other = None
    if gains_path:
        if not os.path.isfile(gains_path):
            raise ReplayError("--gains %s: no such file" % gains_path)
        if _sha256(gains_path) == header["gains"]["sha256"]:
            logged_gains_path = logged_gains_path or gains_path
        else:
            other = gains_path
    r.logged_gains_path = logged_gains_path or find_logged_gains(log_path, header)
    if r.logged_gains_path:
        g = r.logged_gains = _load_gains(r.logged_gains_path)
        if abs(g.ts_s - header["ts_s"]) > 1e-9 * g.ts_s:
            raise ReplayError("%s: field ts_s is %g s, but its gains %s have ts_s %g s: the header does not "
                              "describe the run" % (log_path, header["ts_s"], r.logged_gains_path, g.ts_s))
        r.replayed = replay_rows(header, rows, g)
        r.diffs = [(label, max_abs_diff(r.replayed, rows, cols)) for label, cols in groups(r.names)]
        r.max_diff = max(d for _, d in r.diffs)
        r.exact = r.max_diff <= tol
    elif other is None:
        raise ReplayError(
            "%s was recorded with gains sha256 %s... (%s on the robot) and no file here has that "
            "hash (looked in the log's directory, at that path and in gains/): pass it with --gains FILE "
            "(`make logs` fetches the brick's gains.json next to the logs as gains-<sha256>.json)"
            % (log_path, header["gains"]["sha256"][:16], header["gains"].get("path", "?")))
    else:
        r.notes.append("exact replay skipped: no file with the logged gains' sha256 %s found"
                       % header["gains"]["sha256"][:16])
    if other:
        g = _load_gains(other)
        if abs(g.ts_s - header["ts_s"]) > 1e-12:
            raise ReplayError("--gains %s has ts_s %g s, the log was sampled every %g s: "
                              "its readings cannot drive a controller with another period"
                              % (other, g.ts_s, header["ts_s"]))
        r.other_gains_path = other
        r.other = replay_rows(header, rows, g, as_logged=False)
        r.other_gains = g
        r.other_header = fw_replay.what_if_header(header, g)
        r.other_u_diff = {}
        mine = fw_replay.signals(header, rows, r.logged_gains or g)
        theirs = fw_replay.signals(r.other_header, r.other, g)
        for name, j in zip(vocabulary.ACTUATED, ACTUATED_INPUTS):
            d = theirs.u[:, j] - mine.u[:, j]
            r.other_u_diff[name] = (float(np.max(np.abs(d))), float(np.sqrt(np.mean(d * d))))
        r.other_sat = _sat_fraction(r.other, [c["name"] for c in r.other_header["columns"]])
    return r


# ------------------------------------------------------------------------------ output
def describe(r, tol=DEFAULT_TOL):
    h = r.header
    v = h.get("versions", {})
    g = h["gains"]
    lines = ["log %s" % r.log_path,
             "  recorded %s by tipbot_fw %s (Python %s, numpy %s); %s gains sha256 %s, ts %g s"
             % (h.get("start_wall_time", "?"), v.get("tipbot_fw", "?"), v.get("python", "?"),
                v.get("numpy", "?"), h.get("model_variant", "?"), g["sha256"][:16], h["ts_s"]),
             "  %d ticks in the log (first tick %d of %s), stopped: %s (exit %s)"
             % (len(r.rows), h["first_tick"], h.get("ticks", "?"), h.get("stop_message", "?"),
                h.get("exit_code", "?"))]
    if v.get("tipbot_fw") not in (None, tipbot_fw.__version__):
        lines.append("  note: written by tipbot_fw %s, replayed by %s: differences may come from the version"
                     % (v.get("tipbot_fw"), tipbot_fw.__version__))
    if r.replayed is not None:
        lines.append("replay with the logged gains (%s):" % r.logged_gains_path)
        lines.append("  max |replayed - logged|: " + ", ".join("%s %.3g" % (label, d) for label, d in r.diffs))
        if r.exact:
            lines.append("  replays exactly (max difference %.3g <= %g)" % (r.max_diff, tol))
        else:
            worst = max(r.diffs, key=lambda x: x[1])
            first = _first_bad_tick(r, tol)
            lines.append("  DIFFERS from the log: %s by up to %.3g (> %g), first at row %d (t = %.3f s)"
                         % (worst[0], worst[1], tol, first, r.rows[first, r.names.index("time_s")]))
    for note in r.notes:
        lines.append("  " + note)
    if r.other is not None:
        lines.append("what-if with %s (same readings, open loop):" % r.other_gains_path)
        lines.append("  inputs they would have commanded vs the logged ones, max |diff| (rms): "
                     + ", ".join("u_%s %.3g V (%.3g)" % (n, m, s) for n, (m, s) in r.other_u_diff.items()))
        lines.append("  ticks with a saturated input: %.1f %% (logged run: %.1f %%)"
                     % (100 * r.other_sat, 100 * _sat_fraction(r.rows, r.names)))
    for p in r.plots:
        lines.append("plot %s" % p)
    return "\n".join(lines)


def _sat_fraction(rows, names):
    return float(np.mean((rows[:, names.index("flags")].astype(int) & vocabulary.SATURATION_BITS) != 0))


def _first_bad_tick(r, tol):
    cols = [c for _, cs in groups(r.names) for c in cs]
    d = np.abs(r.replayed[:, cols] - r.rows[:, cols])
    bad = np.nonzero(np.any(~(d <= tol), axis=1))[0]
    return int(bad[0]) if len(bad) else 0


def plot(r, out_dir):
    """inputs and estimates figures (PNG); -> list of paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(out_dir, exist_ok=True)
    stem = os.path.splitext(os.path.basename(r.log_path))[0]
    t = r.rows[:, r.names.index("time_s")]
    gains = r.logged_gains or r.other_gains
    series = []
    if r.other is not None:
        series.append(("replayed with %s" % os.path.basename(r.other_gains_path),
                       fw_replay.signals(r.other_header, r.other, r.other_gains), dict(color="tab:blue", lw=1.0)))
    series.append(("logged", fw_replay.signals(r.header, r.rows, gains), dict(color="k", lw=1.6)))
    if r.replayed is not None:
        series.append(("replayed (logged gains)", fw_replay.signals(r.header, r.replayed, gains),
                       dict(color="tab:orange", lw=1.0, ls="--")))
    # the ticks a long run's log did not keep: shaded between the last row before and the first after
    # (and the lines broken there: a NaN between the parts)
    starts = [i for i, _ in logfile.segment_rows(r.header, len(r.rows))[1:] if 0 < i < len(t)]
    gaps = [(t[i - 1], t[i]) for i in starts]
    t = np.insert(t, starts, np.nan)
    paths = []
    inputs = [("u", j, "u_" + n, "V") for n, j in zip(vocabulary.ACTUATED, ACTUATED_INPUTS)]
    states = [("x_hat", i, "x^_" + n, u) for i, (n, u) in enumerate(zip(vocabulary.STATE_NAMES, vocabulary.STATE_UNITS))]
    for what, panels, ncols in (("inputs", inputs, 2), ("estimates", states, 2)):
        nrows = (len(panels) + ncols - 1) // ncols
        fig, axes = plt.subplots(nrows, ncols, figsize=(11, 2.2 * nrows + 0.8), sharex=True, squeeze=False)
        for ax, (key, j, name, unit) in zip(axes.flat, panels):
            for label, sig, style in series:
                ax.plot(t, np.insert(getattr(sig, key)[:, j], starts, np.nan), label=label, **style)
            for k, (a, b) in enumerate(gaps):
                ax.axvspan(a, b, color="0.85", zorder=0, label="not kept" if k == 0 else None)
            ax.set_ylabel("%s [%s]" % (name, unit))
            ax.grid(True, alpha=0.3)
        for ax in axes[-1]:
            ax.set_xlabel("time since the loop started [s]")
        for ax in list(axes.flat)[len(panels):]:
            ax.set_visible(False)
        title = "%s: %s" % (stem, what)
        if r.exact is not None:
            title += " (replay max |diff| %.2g)" % r.max_diff
        fig.suptitle(title)
        axes.flat[0].legend(loc="best", fontsize="small")
        fig.tight_layout()
        path = os.path.join(out_dir, "%s-%s.png" % (stem, what))
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("replay"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", metavar="LOG", help="a run log (tipbot-*.log: from the brick via `make logs`, "
                    "or from the simulator)")
    ap.add_argument("--gains", metavar="FILE",
                    help="gains to replay with: the logged ones (exact replay) or others (what-if)")
    ap.add_argument("--logged-gains", metavar="FILE", help="the gains file the robot ran, if not found by its hash")
    ap.add_argument("--out", metavar="DIR", default=DEFAULT_OUT, help="plot directory (default out/replay)")
    ap.add_argument("--no-plots", action="store_true", help="print the comparison only")
    ap.add_argument("--tol", type=float, default=DEFAULT_TOL, help="exactness tolerance (default 1e-9)")
    a = ap.parse_args(argv)
    try:
        r = replay_log(a.log, a.gains, a.logged_gains, a.tol)
    except ReplayError as e:
        sys.stderr.write("replay: error: %s\n" % e)
        return 2
    if not a.no_plots:
        r.plots = plot(r, a.out)
    print(describe(r, a.tol))
    return 1 if r.exact is False else 0

