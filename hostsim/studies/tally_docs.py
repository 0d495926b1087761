"""``tools/fault-tally``'s generated blocks in docs/safety.md (hostsim.studies.docblocks): the
tally of faults and bad inputs tried, and the time each process fault took to stop the motors.

``payload`` keeps the tally's counts, its stop times (seconds, 6 significant digits) and what
fell short, in docs/data/fault-tally.json. The tool prints each of its categories and each
fault alone (``tables``); the page groups the kinds of one fault in a row (``group``).
"""
import statistics

SIGNALS = "each catchable termination signal to a driving controller"
PROCESS = ("a process fault: SIGKILL of the controller, the supervisor or the group, SIGSTOP of the controller, "
           "the group, or both")
START = "SIGINT, SIGTERM, SIGHUP or SIGQUIT to the process group during the start"
READERS = "JSON readers (gains, configuration, parameters, scenarios)"


def payload(rows, times, failures, repeat):
    return {"rows": {k: list(v) for k, v in rows.items()},
            "times_s": {k: [float("%.6g" % t) for t in ts] for k, ts in times.items()},
            "failures": list(failures), "repeat": repeat}


def _signal(kind):
    return "to the controller" in kind or "(real-time)" in kind


def group(category):
    """The page's row of one of the tool's categories."""
    if category.startswith("fault: "):
        return SIGNALS if _signal(category) else PROCESS
    if category.startswith("signal during the start"):
        return START
    if category.startswith("JSON readers"):
        return READERS
    return category


def _grouped(items, key):
    """[(row, [values])] in the order the rows first come."""
    out = {}
    for k, v in items:
        out.setdefault(key(k), []).append(v)
    return list(out.items())


def _kinds(what, n):
    return what + (" (%d kinds)" % n if n > 1 and what != READERS else "")


def _tally(data, key):
    lines = ["| what | tried | clear error | stopped safely |", "|---|---|---|---|"]
    total = [0, 0, 0]
    for what, counts in _grouped(data["rows"].items(), key):
        row = [sum(col) for col in zip(*counts)]
        lines.append("| %s | %d | %d | %d |" % (_kinds(what, len(counts)), *row))
        total = [a + b for a, b in zip(total, row)]
    lines.append("| **all** | **%d** | **%d** | **%d** |" % tuple(total))
    if data["failures"]:
        lines += ["", "Short of the mark:", ""] + ["- " + f for f in data["failures"]]
    return "\n".join(lines)


def _times(data, key):
    lines = ["| fault | runs | motors stopped after: min | median | max |", "|---|---|---|---|---|"]
    for kind, runs in _grouped(data["times_s"].items(), key):
        ts = [t for r in runs for t in r]
        lines.append("| %s | %d | %.1f ms | %.1f ms | %.1f ms |" % (
            _kinds(kind, len(runs)), len(ts), 1e3 * min(ts), 1e3 * statistics.median(ts), 1e3 * max(ts)))
    return "\n".join(lines)


def tally(data):
    return _tally(data, group)


def stop_times(data):
    return ("Each process fault %d times, every motor's files polled every 0.2 ms; the signals' kinds in one "
            "row.\n\n" % data["repeat"]) + _times(data, lambda kind: "any termination signal" if _signal(kind) else kind)


def tables(data):
    """What the tool prints: each category and each fault alone."""
    same = lambda k: k
    return _tally(data, same) + ("\n\n" + _times(data, same) if data["times_s"] else "")


BLOCKS = {
    "fault-tally": ("docs/safety.md", tally),
    "fault-stop-times": ("docs/safety.md", stop_times),
}
