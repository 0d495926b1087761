"""Live telemetry from the robot: scrolling plots of what it does, and a recording.

    python -m hostsim watch [--port 5005] [--record FILE.csv] [--duration S] [--window S]
                            [--snapshot FILE.png] [--no-window] [-- COMMAND ...]
    python -m hostsim watch --from FILE.csv [--snapshot FILE.png] [--no-window]
    (make watch HOST=... starts a run on the brick with its telemetry pointed here)

Listens for the datagrams of `python3 -m tipbot_fw run --telemetry HOST:PORT` (UDP, decoded by
tipbot_fw.record.telemetry: docs/telemetry.md) and shows the last --window seconds: the controller's
estimates of the link angles and wheel displacements (the Kalman filter's x^, or the
detector's x~), the inputs, the disturbance estimate and the tick's duration with the overruns; the
title says the battery, the datagram rate and how many were lost on the way (gaps in their
sequence numbers) or not sent by the brick. Without a display (or with --no-window) it only
records and, with --snapshot, saves the last view as a PNG.

--record FILE writes every datagram as a CSV row (the export's column names, tipbot's log
columns with their units, plus run, seq, tick, overruns and send_errors): the values are those
the run's log has for the same tick. After `--`, COMMAND runs while watch listens (e.g. `make
run` on the brick) and watch exits with its status once it has ended (keeping the window open
until it is closed). --from FILE shows a recording instead of listening.
"""
import argparse
import bisect
import csv
import os
import select
import socket
import subprocess
import sys
import time

import hostsim
from tipbot_fw.record import telemetry

from hostsim.errors import TipbotError
from hostsim.logs.export import csv_header, format_value
from tipbot_fw import vocabulary
from tipbot_fw.cores.detector_rows import DetectorRows

NAN = float("nan")
DEFAULT_PORT = 5005
DEFAULT_WINDOW_S = 10.0
REDRAW_S = 0.1
LINGER_S = 1.0          # after COMMAND ends, late datagrams are still taken this long
# (title, unit, [(decoded field, label, scale)]) of each panel; the tick panel is drawn apart
PANELS = (
    ("links", "rad", [("xt_th1", "th1", 1.0), ("xt_th2", "th2", 1.0), ("xt_th3", "th3", 1.0)]),
    ("wheels", "m", [("xt_d_r", "d_r", 1.0), ("xt_d_l", "d_l", 1.0)]),
    ("speeds", "m/s",
     [("xt_d_r_dot", "d_r'", 1.0), ("xt_d_l_dot", "d_l'", 1.0), ("ref_v_r", "course r", 1.0), ("ref_v_l", "course l", 1.0)]),
    ("inputs", "V", [("u_r", "u_r", 1.0), ("u_l", "u_l", 1.0), ("u_th2", "u_th2", 1.0), ("u_th3", "u_th3", 1.0)]),
    ("disturbance estimate", "V", [("w_r", "w_r", 1.0), ("w_l", "w_l", 1.0), ("w_th2", "w_th2", 1.0),
                                   ("w_th3", "w_th3", 1.0)]),
    ("tick duration", "ms", [("tick_s", "read..write", 1e3)]),
)
COUNTERS = ("run", "seq", "tick", "overruns", "send_errors")
_UNITS = dict(DetectorRows.columns)
FIELDS = list(telemetry.DECODED)
# a driven run's reference: plotted, NaN (no line) for a run that stands; not recorded (a
# recording's columns are those of every run)
PLOTTED = FIELDS + list(telemetry.REFERENCE_NAMES)
RECORD_COLUMNS = [(c, "") for c in COUNTERS] + [(f, _UNITS[f]) for f in FIELDS]


class WatchError(TipbotError):
    """A recording that cannot be read, a port that cannot be used."""


class Telemetry(object):
    """What has been received: one list per field, runs told apart (a tick number going back
    is a new run of the firmware), counts of what was lost."""

    def __init__(self):
        self.data = {f: [] for f in COUNTERS + tuple(PLOTTED)}
        self.runs = 0
        self.received = self.bad = 0
        self.lost = 0               # sequence numbers skipped
        self.last = None            # the newest datagram's values
        self.start = 0              # where the newest run's values begin
        self.sender = None

    def add(self, v):
        last = self.last
        if last is None or v["tick"] < last["tick"] or v["seq"] < last["seq"]:
            self.runs += 1
            self.start = len(self.data["seq"])
        elif v["seq"] > last["seq"] + 1:
            self.lost += v["seq"] - last["seq"] - 1
        v["run"] = self.runs
        for f, values in self.data.items():
            values.append(v.get(f, NAN))
        self.received += 1
        self.last = v

    def window(self, seconds):
        """(first, end) indices of this run's values within its last `seconds` (0: all)."""
        end = len(self.data["time_s"])
        if not end:
            return 0, 0
        times = self.data["time_s"]
        first = self.start if seconds <= 0 else max(self.start, bisect.bisect_left(times, times[-1] - seconds, self.start))
        return first, end


class Recorder(object):
    def __init__(self, path):
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            self.f = open(path, "w", newline="")
        except OSError as e:
            raise WatchError("--record %s: %s" % (path, e.strerror or e))
        self.w = csv.writer(self.f, lineterminator="\n")
        self.w.writerow(csv_header(RECORD_COLUMNS))

    def write(self, v):
        self.w.writerow([format_value(v[n]) for n, _ in RECORD_COLUMNS])

    def close(self):
        self.f.close()


def read_recording(path):
    """A recording (--record) as a Telemetry."""
    tel = Telemetry()
    names = csv_header(RECORD_COLUMNS)
    try:
        with open(path, newline="") as f:
            rows = csv.reader(f)
            if next(rows, None) != names:
                raise WatchError("%s: not a recording of hostsim watch (its header differs)" % path)
            for i, row in enumerate(rows):
                try:
                    v = {n: float(x) for (n, _), x in zip(RECORD_COLUMNS, row)}
                except ValueError:
                    raise WatchError("%s: row %d: not a number" % (path, i + 2))
                if len(row) != len(names):
                    raise WatchError("%s: row %d: %d values, the header has %d" % (path, i + 2, len(row), len(names)))
                tel.add(v)
    except OSError as e:
        raise WatchError("%s: cannot read: %s" % (path, e.strerror or e))
    return tel


# ------------------------------------------------------------------------------ the view
class View(object):
    """The figure: one panel per PANELS entry, the last `window_s` seconds of the newest run."""

    def __init__(self, plt, window_s, period_s=0.005):
        self.plt = plt
        self.window_s = window_s
        self.fig, axes = plt.subplots(len(PANELS), 1, sharex=True, figsize=(10, 10))
        self.lines = []
        for ax, (title, unit, fields) in zip(axes, PANELS):
            for field, label, scale in fields:
                style = dict(lw=0, marker="|", ms=4) if field == "tick_s" else dict(lw=1.2)
                (line,) = ax.plot([], [], label=label, **style)
                self.lines.append((line, field, scale))
            ax.set_ylabel("%s [%s]" % (title, unit))
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper left", fontsize=8, ncol=4)
        self.tick_ax = axes[-1]
        self.tick_ax.axhline(period_s * 1e3, color="0.5", ls="--", lw=1, label="period")
        (self.overrun_line,) = self.tick_ax.plot([], [], "rv", ms=6, label="overrun")
        self.tick_ax.legend(loc="upper left", fontsize=8, ncol=4)
        axes[-1].set_xlabel("time since the run's first tick [s]")
        self.axes = axes
        self.fig.tight_layout(rect=(0, 0, 1, 0.96))

    def update(self, tel, note=""):
        first, end = tel.window(self.window_s)
        d = tel.data
        t = d["time_s"][first:end]
        rate_hz = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0
        for line, field, scale in self.lines:
            line.set_data(t, [x * scale for x in d[field][first:end]])
        flags = d["flags"][first:end]
        over = [i for i, f in enumerate(flags) if int(f) & vocabulary.FLAG_BITS["overrun"]]
        self.overrun_line.set_data([t[i] for i in over], [d["tick_s"][first + i] * 1e3 for i in over])
        for ax in self.axes:
            ax.relim()
            ax.autoscale_view(scalex=False)
        if t:
            right = max(t[-1], self.window_s if self.window_s > 0 else t[-1])
            self.axes[0].set_xlim(right - self.window_s if self.window_s > 0 else t[0], right)
        last = tel.last or {}
        self.fig.suptitle("tipbot telemetry%s: battery %s V, %d overruns, %.1f datagrams/s, %d lost, %d not sent%s" % (
            " from %s" % tel.sender if tel.sender else "",
            "%.2f" % last["battery_v"] if last else "-", last.get("overruns", 0), rate_hz, tel.lost,
            last.get("send_errors", 0), note), fontsize=10)


def pyplot(window):
    """matplotlib.pyplot with a window if one can be opened (and `window`), else Agg."""
    import matplotlib
    if window and (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or sys.platform in ("darwin", "win32")):
        try:
            import matplotlib.pyplot as plt
            plt.ion()
            if matplotlib.get_backend().lower() != "agg":
                return plt, True
        except ImportError:
            pass
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt, False


# ------------------------------------------------------------------------------ listening
def listen(port, bind="0.0.0.0"):
    try:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind((bind, port))     # no SO_REUSEADDR: a second watch on the port is an error, not a thief
    except OSError as e:
        raise WatchError("cannot listen on UDP %s:%d: %s" % (bind, port, e.strerror or e))
    sock.setblocking(False)
    return sock


def drain(sock, tel, recorder):
    """Take every datagram waiting on sock; -> how many."""
    n = 0
    while True:
        try:
            data, addr = sock.recvfrom(2048)
        except (BlockingIOError, InterruptedError):
            return n
        try:
            v = telemetry.decode(data)
        except telemetry.TelemetryError:
            tel.bad += 1
            continue
        if tel.sender is None:
            tel.sender = addr[0]
            print("watch: receiving telemetry from %s" % addr[0], flush=True)
        tel.add(v)
        if recorder:
            recorder.write(v)
        n += 1


def watch(port, record=None, duration_s=None, window_s=DEFAULT_WINDOW_S, snapshot=None, window=True,
          command=None, bind="0.0.0.0"):
    """Listen (and run `command`) until duration_s, the command's end or Ctrl-C. -> (exit status, Telemetry)."""
    sock = listen(port, bind)
    recorder = Recorder(record) if record else None
    plt, interactive = pyplot(window)
    if window and not interactive:
        kept = [what for what in ("the datagrams to %s" % record if record else None,
                                  "the view to %s" % snapshot if snapshot else None) if what]
        print("watch: no display: %s" % ("keeping " + " and ".join(kept) if kept else
                                         "nothing is drawn or kept (give RECORD=file.csv or SNAPSHOT=file.png); "
                                         "the summary comes at the end"), flush=True)
    view = View(plt, window_s) if interactive or snapshot else None
    tel = Telemetry()
    child = subprocess.Popen(command) if command else None
    status, t0, ended = 0, time.monotonic(), None
    print("watch: listening on UDP port %d%s" % (port, " (Ctrl-C ends)" if child is None else ""), flush=True)
    try:
        while True:
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            if child is not None and ended is None and child.poll() is not None:
                status, ended = child.returncode, now
            if ended is not None and now - ended >= LINGER_S:
                break
            if interactive and not plt.fignum_exists(view.fig.number):
                break
            ready = select.select([sock], [], [], REDRAW_S if not interactive else 0)[0]
            if ready:
                drain(sock, tel, recorder)
            if interactive:
                view.update(tel)
                plt.pause(REDRAW_S)
    except KeyboardInterrupt:
        pass
    finally:
        if recorder:
            recorder.close()
        sock.close()
    if child is not None and ended is None:
        if child.poll() is None:
            print("watch: waiting for %s to end" % " ".join(command), flush=True)
        status = child.wait()
    if view is not None:
        view.update(tel)
        if snapshot:
            save(view, snapshot, "python -m hostsim watch --port %d" % port)
        if interactive and plt.fignum_exists(view.fig.number):
            print("watch: close the window to end", flush=True)
            plt.ioff()
            plt.show()
    return status, tel


def save(view, path, made_by):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    view.fig.savefig(path, dpi=80, metadata={"Software": made_by})


def summary(tel, record=None):
    text = "watch: %d datagrams in %d run%s, %d lost on the way, %d not sent by the brick, %d not tipbot's" % (
        tel.received, tel.runs, "" if tel.runs == 1 else "s", tel.lost,
        int(tel.last["send_errors"]) if tel.last else 0, tel.bad)
    return text + ("; recorded in %s" % record if record else "")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    command = None
    if "--" in argv:
        i = argv.index("--")
        argv, command = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(prog=hostsim.command("watch"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--port", type=int, default=DEFAULT_PORT, help="UDP port to listen on (default %d)" % DEFAULT_PORT)
    ap.add_argument("--bind", default="0.0.0.0", help="address to listen on (default all)")
    ap.add_argument("--record", metavar="FILE", help="write every datagram to FILE (CSV)")
    ap.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    ap.add_argument("--window", type=float, default=DEFAULT_WINDOW_S, metavar="S",
                    help="seconds shown (default %g; 0: the whole run)" % DEFAULT_WINDOW_S)
    ap.add_argument("--snapshot", metavar="FILE.png", help="save the last view as a PNG")
    ap.add_argument("--no-window", action="store_true", help="no window, even with a display")
    ap.add_argument("--from", dest="recording", metavar="FILE", help="show a recording (--record) instead of listening")
    a = ap.parse_args(argv)
    try:
        if a.recording:
            tel = read_recording(a.recording)
            plt, interactive = pyplot(not a.no_window)
            view = View(plt, a.window)
            view.update(tel, note=" (recording %s)" % os.path.basename(a.recording))
            if a.snapshot:
                save(view, a.snapshot, "python -m hostsim watch --from %s" % os.path.basename(a.recording))
            if interactive:
                plt.ioff()
                plt.show()
            print(summary(tel))
            return 0
        status, tel = watch(a.port, a.record, a.duration, a.window, a.snapshot, not a.no_window, command, a.bind)
    except WatchError as e:
        sys.stderr.write("watch: error: %s\n" % e)
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("watch: interrupted\n")
        return 130
    print(summary(tel, a.record))
    return status
