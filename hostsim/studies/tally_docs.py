"""``tools/fault-tally``'s generated blocks in docs/safety.md (hostsim.studies.docblocks): the tally of
faults and bad inputs tried, and the time each process fault took to stop the motors.

``payload(tally)`` keeps the tally's counts, its stop times (seconds, 6 significant digits) and
what fell short, in docs/data/fault-tally.json; the tool prints the same tables (``tables``).
"""
import statistics


def payload(rows, times, failures, repeat):
    return {"rows": {k: list(v) for k, v in rows.items()},
            "times_s": {k: [float("%.6g" % t) for t in ts] for k, ts in times.items()},
            "failures": list(failures), "repeat": repeat}


def tally(data):
    lines = ["| what | tried | clear error | stopped safely |", "|---|---|---|---|"]
    total = [0, 0, 0]
    for cat, (n, c, s) in data["rows"].items():
        lines.append("| %s | %d | %d | %d |" % (cat, n, c, s))
        total = [a + b for a, b in zip(total, (n, c, s))]
    lines.append("| **all** | **%d** | **%d** | **%d** |" % tuple(total))
    if data["failures"]:
        lines += ["", "Short of the mark:", ""] + ["- " + f for f in data["failures"]]
    return "\n".join(lines)


def stop_times(data):
    lines = ["Each process fault %d times; every motor's files polled every 0.2 ms." % data["repeat"], "",
             "| fault | runs | motors stopped after: min | median | max |", "|---|---|---|---|---|"]
    for kind, ts in data["times_s"].items():
        lines.append("| %s | %d | %.1f ms | %.1f ms | %.1f ms |" % (
            kind, len(ts), 1e3 * min(ts), 1e3 * statistics.median(ts), 1e3 * max(ts)))
    return "\n".join(lines)


def tables(data):
    """Both tables, as the tool prints them."""
    return tally(data) + ("\n\n" + stop_times(data) if data["times_s"] else "")


BLOCKS = {
    "fault-tally": ("docs/safety.md", tally),
    "fault-stop-times": ("docs/safety.md", stop_times),
}
