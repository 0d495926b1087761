"""Your robot's parameters from its description and its experiments (issue 24).

    python -m hostsim fit-robot --description params/my-robot.json --fall FALL.log \\
        --swing SWING2.log --swing SWING3.log --out params/my-robot-fitted.json

The description (hostsim.model.description: masses, balance points, estimated inertias, with
their uncertainty; its motors, e.g. from ``identify``) is the prior; the experiments
(tipbot_fw.experiments, fitted by tipbot_fw.bodyfit with the description's motor model) measure

- the fall: I_roll / Mh, the robot's inertia about the wheels' contact over its lever (the fall
  pole's square is g over it);
- the swing of joint 3: link 3's lever a3 = m3 l3 and inertia b3 = J3 + m3 l3^2 (the rotor's Jm
  taken off);
- the swing of joint 2: a2 and b2 of links 2 and 3 about joint 2 (hostsim.model.bodies);
- the axle swing (joint 1): the whole robot's lever about the axle a1 = M h and its inertia there
  I_a (the wheel motors' rotors taken off).

(In hostsim.model, not hostsim.logs: the owners' study, hostsim.studies.robot_study, runs it.)
The nine link parameters (m_i, l_i, J_i) are the maximum a posteriori estimate: least squares in
their logarithms of the prior's deviations over its standard deviations and of each measurement's
deviation over its standard deviation: the fit's own (tipbot_fw.bodyfit) and a floor for what the
fit's model leaves out (MEASUREMENT_FLOOR, tipbot_fw.bodyfit.MODEL_ERROR, which the pre-flight
check uses too: 2 % for the fall, 8 % for joint 2's lever and 4 % for joint 3's, 5 % for the
axle's, 30 % for a swing's inertia and 50 % for joint 3's; why, there). The posterior covariance
(the inverse of the Gauss-Newton matrix at the optimum) goes into the file's ``uncertainty``
block (hostsim.model.spread), which ``make gains PARAMS=FILE`` uses: its design holds the robots
two standard deviations along the loosest axes, and its verdict says whether to deploy.
"""
import argparse
import json
import math
import os
import sys

import hostsim
import numpy as np
from scipy.optimize import least_squares

from hostsim.errors import TipbotError
from tipbot_fw.record import logfile
from hostsim.model import bodies
from hostsim.model.params import parse_params
from hostsim.model.spread import spread_from_doc
from tipbot_fw import bodyfit, fields

LINK_PARAMETERS = ("m1_kg", "m2_kg", "m3_kg", "l1_m", "l2_m", "l3_m", "j1_kg_m2", "j2_kg_m2", "j3_kg_m2")
MEASUREMENT_FLOOR = bodyfit.MODEL_ERROR
DEFAULT_PRIOR_SIGMA = 0.5


class RobotFitError(TipbotError):
    pass


def read_log(path, error):
    """(header, rows, names) of an experiment log (tipbot_fw.record.logfile); error naming the file."""
    try:
        header, rows = logfile.read_log(path)
    except (OSError, logfile.LogFormatError) as e:
        raise error("%s: cannot read: %s" % (path, e))
    return header, rows, [c["name"] for c in header.get("columns", [])]


def measure(params, fall_log=None, swing_logs=()):
    """Fit the experiment logs with the parameters' motors and wheels -> {name: (value, rel sigma,
    details)}: fall_ratio (I_roll / Mh), lever3, inertia3, lever2, inertia2, lever1, inertia1 (inertias
    without the rotors)."""
    out = {}
    if fall_log:
        header, rows, _ = read_log(fall_log, RobotFitError)
        _kind(fall_log, header, "fall")
        e = bodies.wheel_term(params) / bodies.levers(params)[0]
        try:
            fit = bodyfit.fit_fall(bodyfit.signals(header, rows), params["rw_m"], params["g_m_s2"], e)
        except bodyfit.FitError as exc:
            raise RobotFitError("%s: %s" % (fall_log, exc))
        out["fall_ratio"] = (fit["ratio_m"], math.hypot(2 * fit["pole_rel_se"], MEASUREMENT_FLOOR["fall_ratio"]), fit)
    logs = {}
    for path in swing_logs:
        header, rows, _ = read_log(path, RobotFitError)
        _kind(path, header, "swing")
        logs[header.get("joint")] = (path, header, rows)
    for joint in (3, 2, 1):
        if joint not in logs:
            continue
        path, header, rows = logs[joint]
        k_v, c, jm = bodyfit.motor_constants(params, joint)
        lever3 = out["lever3"][0] if "lever3" in out else bodies.levers(params)[2]
        try:
            fit = bodyfit.fit_swing(bodyfit.signals(header, rows), joint, k_v, c, params["g_m_s2"],
                                    lever3=lever3 if joint == 2 else None)
        except bodyfit.FitError as exc:
            raise RobotFitError("%s: %s" % (path, exc))
        floor = MEASUREMENT_FLOOR["lever%d" % joint]
        out["lever%d" % joint] = (fit["lever_kg_m"], math.hypot(fit["lever_se"] / fit["lever_kg_m"], floor), fit)
        inertia = fit["inertia_kg_m2"] - jm
        if inertia > 0:
            out["inertia%d" % joint] = (inertia, math.hypot(fit["inertia_se"] / inertia,
                                                             MEASUREMENT_FLOOR.get("inertia%d" % joint, MEASUREMENT_FLOOR["inertia"])), fit)
    return out


def _kind(path, header, kind):
    if header.get("kind") != kind:
        raise RobotFitError("%s: not a %s test's log (kind %r)" % (path, kind, header.get("kind")))
    if header.get("stop_reason") != "completed":
        raise RobotFitError("%s: the %s test did not complete (%s): do it again" % (path, kind,
                                                                                    header.get("stop_message")))


def model_value(name, p):
    if name == "fall_ratio":
        return bodies.rolling_inertia(p) / bodies.levers(p)[0]
    j = int(name[-1])
    if name.startswith("lever"):
        return bodies.levers(p)[j - 1]
    return bodies.joint_inertias(p)[j - 1]


def fit(params, prior_sigma, measured):
    """MAP of the link parameters (module docstring) -> (parameters, log-covariance (9 x 9))."""
    x0 = np.log([params[n] for n in LINK_PARAMETERS])
    s0 = np.array([prior_sigma.get(n, DEFAULT_PRIOR_SIGMA) for n in LINK_PARAMETERS])
    names = sorted(measured)

    def with_x(x):
        p = dict(params)
        p.update({n: float(math.exp(v)) for n, v in zip(LINK_PARAMETERS, x)})
        return p

    def resid(x):
        p = with_x(x)
        r = list((x - x0) / s0)
        for n in names:
            value, sigma, _ = measured[n]
            r.append((math.log(model_value(n, p)) - math.log(value)) / sigma)
        return np.array(r)
    sol = least_squares(resid, x0, method="lm", x_scale=s0)
    jac = sol.jac
    cov = np.linalg.inv(jac.T @ jac)
    return with_x(sol.x), (cov + cov.T) / 2


def fitted_document(desc_doc, params, cov, measured, sources):
    """The description's document with the link parameters replaced and the uncertainty block
    the posterior's (the other parameters keep their prior's diagonal)."""
    doc = json.loads(json.dumps(desc_doc))
    old = spread_from_doc(desc_doc, "<description>")
    what = ", ".join(sources)
    for i, n in enumerate(LINK_PARAMETERS):
        doc["parameters"][n] = {"value": float("%.6g" % params[n]),
                                "source": "fitted: the description and %s (python -m hostsim fit-robot)" % what,
                                "uncertainty": float("%.3g" % math.sqrt(cov[i, i]))}
    names = list(LINK_PARAMETERS)
    extra = [n for n in (old.names if old else ()) if n not in names]
    full = np.zeros((len(names) + len(extra),) * 2)
    full[:9, :9] = cov
    for k, n in enumerate(extra):
        full[9 + k, 9 + k] = old.rel_sigma(n) ** 2
    doc["uncertainty"] = {
        "parameters": names + extra, "log_covariance": [[float("%.6g" % v) for v in row] for row in full],
        "source": "python -m hostsim fit-robot: the description as the prior, %s" % what,
        "measurements": {n: {"value": v, "rel_sigma": s,
                             "summary": "%s %.4g +-%.1f %% (model after the fit %.4g)" % (
                                 n, v, 100 * s, model_value(n, params), )} for n, (v, s, _) in sorted(measured.items())}}
    parse_params(doc, "<fitted>")
    return doc


def fit_files(description, fall_log=None, swing_logs=()):
    """-> (fitted document, parameters, measured) from a description file and the logs."""
    desc_doc = fields.read_object(description, RobotFitError)
    params = parse_params(desc_doc, description)
    spread = spread_from_doc(desc_doc, description)
    prior = {n: (spread.rel_sigma(n) if spread else DEFAULT_PRIOR_SIGMA) or DEFAULT_PRIOR_SIGMA for n in LINK_PARAMETERS}
    measured = measure(params, fall_log, swing_logs)
    if not measured:
        raise RobotFitError("no experiment given: --fall and/or --swing")
    fitted, cov = fit(params, prior, measured)
    sources = [os.path.basename(x) for x in ([fall_log] if fall_log else []) + list(swing_logs)]
    return fitted_document(desc_doc, fitted, cov, measured, sources), fitted, measured


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("fit-robot"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--description", required=True, help="the parameters file python -m hostsim describe wrote")
    ap.add_argument("--fall", metavar="LOG", help="the fall test's log (python3 -m tipbot_fw fall-test)")
    ap.add_argument("--swing", metavar="LOG", action="append", default=[],
                    help="a swing test's log (python3 -m tipbot_fw swing-test --joint J), once per joint")
    ap.add_argument("--out", required=True, help="the fitted parameters file to write (then: make gains PARAMS=...)")
    a = ap.parse_args(argv)
    try:
        doc, params, measured = fit_files(a.description, a.fall, a.swing)
    except TipbotError as e:
        print("fit-robot: error: %s" % e, file=sys.stderr)
        return 2
    for n, (v, s, _) in sorted(measured.items()):
        print("  %-10s measured %.4g +-%.1f %%, the fitted model's %.4g" % (n, v, 100 * s, model_value(n, params)))
    print("  fall pole %.3f 1/s; levers %s kg m" % (bodies.fall_pole(params),
                                                    ", ".join("%.4g" % v for v in bodies.levers(params))))
    for n in LINK_PARAMETERS:
        e = doc["parameters"][n]
        print("  %-9s %.4g +-%.0f %%" % (n, e["value"], 100 * e["uncertainty"]))
    tmp = a.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, a.out)
    print("wrote %s; next: make gains PARAMS=%s" % (a.out, a.out))
    return 0
