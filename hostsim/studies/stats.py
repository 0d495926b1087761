"""Summaries of a distribution over many runs: median, 95th percentile and maximum."""
import numpy as np

KEYS = ("median", "p95", "max")


def distribution(values):
    """{median, p95, max} of the values (None each when there are none)."""
    if not len(values):
        return dict.fromkeys(KEYS)
    return {"median": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95)),
            "max": max(values)}


def trio(d, fmt, sep="/"):
    """'median/p95/max' of a distribution summary ('-' where there were no runs)."""
    return sep.join("-" if d[k] is None else fmt % d[k] for k in KEYS)
