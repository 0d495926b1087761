"""How well a parameters file knows its robot: the ``uncertainty`` block an owner's description
(hostsim.model.description) or fit (hostsim.model.robotfit) writes, and the robots it spans.

The block, beside ``parameters`` in the file (hostsim.model.params ignores it)::

    "uncertainty": {"parameters": ["m1_kg", ...], "log_covariance": [[...], ...],
                    "measurements": {...}, "source": "..."}

``log_covariance`` is the covariance of the natural logarithms of those parameters (relative
errors, with their correlations: a swing measures m3 l3 well and m3 and l3 each less well). The
gains design (hostsim.model.gains) makes its law hold, besides its usual uncertainty set, the
robots ``K_SIGMA`` standard deviations along each principal axis of that covariance whose
standard deviation exceeds ``MIN_AXIS_SIGMA``: wider where the fit is loose, nothing added where
it is tight.
"""
import math

import numpy as np

from hostsim.errors import ParameterError
from hostsim.model.params import REQUIRED
from tipbot_fw import fields

K_SIGMA = 2.0
MIN_AXIS_SIGMA = 0.01
# Which experiment measures which parameters: what to measure again where a fit is loose.
MEASUREMENT_OF = {"1": "the fall test and the axle swing (python3 -m tipbot_fw fall-test; swing-test --joint 1)",
                  "2": "the swing of joint 2 (python3 -m tipbot_fw swing-test --joint 2)",
                  "3": "the swing of joint 3 (python3 -m tipbot_fw swing-test --joint 3)"}


class Spread:
    """The parameters' log-covariance; robots() -> the design's extra robots."""

    def __init__(self, names, cov, measurements=None, source=""):
        self.names = tuple(names)
        self.cov = np.array(cov, dtype=float)
        self.measurements = measurements or {}
        self.source = source

    def rel_sigma(self, name):
        """The relative standard deviation of one parameter (0 if not uncertain)."""
        if name not in self.names:
            return 0.0
        i = self.names.index(name)
        return math.sqrt(max(self.cov[i, i], 0.0))

    def axes(self):
        """[(sigma, direction)] of the principal axes beyond MIN_AXIS_SIGMA, the loosest first."""
        w, v = np.linalg.eigh((self.cov + self.cov.T) / 2)
        out = []
        for i in np.argsort(w)[::-1]:
            sigma = math.sqrt(max(w[i], 0.0))
            if sigma > MIN_AXIS_SIGMA:
                d = v[:, i] * (1.0 if v[np.argmax(np.abs(v[:, i])), i] > 0 else -1.0)
                out.append((sigma, d))
        return out

    def robots(self, params):
        """[(label, parameters)]: params moved K_SIGMA along each axis, both ways."""
        out = []
        for k, (sigma, d) in enumerate(self.axes()):
            for sign in (1, -1):
                p = dict(params)
                for name, x in zip(self.names, d):
                    p[name] = params[name] * math.exp(sign * K_SIGMA * sigma * x)
                out.append(("fit axis %d %+g sigma" % (k + 1, sign * K_SIGMA), p))
        return out

    def loosest_link(self, label=None):
        """The link ('1', '2', '3') whose parameters weigh most in an axis (the one a robot's label
        names, else the loosest)."""
        axes = self.axes()
        if not axes:
            return None
        k = 0
        if label and label.startswith("fit axis "):
            k = int(label.split()[2]) - 1
        d = axes[k][1]
        weight = {}
        for name, x in zip(self.names, d):
            link = name[1] if name[:1] in "mlj" and name[1:2] in "123" else None
            if link:
                weight[link] = weight.get(link, 0.0) + x * x
        return max(weight, key=weight.get) if weight else None

    def describe(self):
        return {"source": self.source, "k_sigma": K_SIGMA, "min_axis_sigma": MIN_AXIS_SIGMA,
                "axes": [{"sigma": float(s), "direction": {n: float(x) for n, x in zip(self.names, d) if abs(x) > 1e-3}}
                         for s, d in self.axes()]}


def spread_from_doc(doc, source):
    """The Spread of a parameters document, or None when it has no ``uncertainty`` block;
    ParameterError naming the file and field."""
    block = doc.get("uncertainty") if isinstance(doc, dict) else None
    if block is None:
        return None
    f = fields.Fields(source, ParameterError)
    f.check("uncertainty", block, fields.obj)
    raw = block.get("parameters")
    names = f.check("uncertainty.parameters", raw, fields.strings(len(raw) if isinstance(raw, list) else -1))
    for i, n in enumerate(names):
        if n not in REQUIRED:
            f.fail("uncertainty.parameters[%d]" % i, "is %r, not a parameter" % n)
    cov = np.array(f.check("uncertainty.log_covariance", block.get("log_covariance"),
                           fields.matrix(len(names), len(names))), dtype=float)
    if np.max(np.abs(cov - cov.T)) > 1e-9 * max(1.0, float(np.max(np.abs(cov)))):
        f.fail("uncertainty.log_covariance", "must be symmetric")
    if len(names) and (np.min(np.linalg.eigvalsh(cov)) < -1e-12 or np.max(np.diag(cov)) > 1.0):
        f.fail("uncertainty.log_covariance", "must be a covariance of relative errors (positive semi-definite, "
                                            "no standard deviation beyond 100 %)")
    return Spread(names, cov, block.get("measurements") if isinstance(block.get("measurements"), dict) else {},
                  block.get("source", ""))


def load_spread(path):
    return spread_from_doc(fields.read_object(path, ParameterError), path)
