"""Motor identification (the paper's Section 4, Table 2, Figure 3) from identify logs.

    python -m hostsim identify LOG... [--role ROLE]... [--ra-ohm R] [--jm-kg-m2 J]
        [--load-inertia-kg-m2 J] [--params FILE] [--write-params OUT.json] [--out DIR] [--no-plots]

A LOG comes from the brick: ``python3 -m tipbot_fw identify --port outA`` drove one motor at a
fixed duty d from standstill, then let it coast (open circuit), and logged the encoder count
and the battery voltage Vb (docs/log-format.md, "Identify logs"). This tool fits

* the step response: the model of Section 4, G(s) = Omega(s)/V(s) = phi / (alpha s + 1),
  driven by the voltage the motor got, V(t) = d/100 x Vb(t) (the logged battery readings,
  held), from rest, after a dead time t_d >= 0 (driver latency; --no-dead-time fixes it at 0).
  It fits the POSITION, not a differentiated speed: theta(t) = p0 + integral of omega, which
  the encoder's 1-degree counts measure without noise. Each change of the count is one data
  point: the count went from c' to c between two reads (times t', t), i.e. the shaft passed
  the boundaries c'+1..c at about (t' + t)/2, where the position was (c' + 1 + c)/2 counts
  (the encoder's phase is absorbed by p0);
* the run-down after the coast command: J omega' = -beta omega, so
  omega(t) = omega_c exp(-(t - t_c) / tau_c), tau_c = Jm / beta, fitted the same way. A
  Coulomb (constant) friction torque makes the speed fall linearly instead; the fit of
  omega' = -(omega + c) / tau_c says how much: c is the speed below which Coulomb friction
  outweighs the viscous one, and when c exceeds the speed at the coast command the run-down
  is called Coulomb-dominated (tau_c is then only a rough equivalent).

What the three measured numbers determine (ideal DC motor, inductance neglected)::

    J w' = (Km/Ra) (u - Ke w) - beta w          driven:  phi = Km / (Ra beta + Ke Km)
                                                         alpha = Ra J / (Ra beta + Ke Km)
    J w' = -beta w                               coasting: tau_c = J / beta

Divided by J these are three rates: phi/alpha = Km/(Ra J), 1/alpha = (Ke Km/Ra + beta)/J,
1/tau_c = beta/J. So, with r = alpha/tau_c (the share of the damping that is friction):

    Ke  = (1/alpha - 1/tau_c) / (phi/alpha) = (1 - r) / phi       (needs no assumption)
    Km / J = phi Ra / alpha,   beta / J = 1 / tau_c               (only ratios to J)

Five unknowns (beta, Ke, Km, Ra, Jm), three measurements: two must be supplied.

* Ra: ``--ra-ohm`` (measure the motor's terminals with an ohmmeter), else the value of the
  role in the parameters file. Ra itself never enters phi and alpha; only Km, beta and Jm
  scale with it.
* Either Km = Ke (the default: for an ideal DC motor in SI units the torque constant in N m/A
  equals the back-EMF constant in V s/rad), then Jm = Km alpha / (phi Ra) and
  beta = Jm / tau_c; or ``--jm-kg-m2`` (a known inertia), then Km = phi Ra Jm / alpha and
  beta = Jm / tau_c.

Assumptions, stated with the results: coasting is an open circuit (stop_action coast); the
shaft turned freely (no load but what turns with it: ``--load-inertia-kg-m2`` subtracts, e.g.,
a wheel left on it, Table 1's Jw); viscous friction only in the model; the voltage at the
motor is duty x battery voltage (the H-bridge's drop counts as resistance). Table 2 itself
has Ke != Km (1.6x for motor 1), which no step-and-coast test can tell from a different Jm:
with the default assumption such a motor comes out with its true phi, alpha, tau_c and Ke,
Km = Ke, and Jm and beta scaled by Ke/Km.

Output: per log the fit and the parameters beside Table 2's motor for that role (right wheel
= motor 1, left wheel = 2, joint 2 = 3, joint 3 = 5); a PNG of measured and fitted speed
against time, one panel per log, as in Figure 3 (--out, default out/identify/); with
``--write-params OUT.json`` a copy of the parameters file (--params) with the identified
roles' five motor fields replaced (sources say from which log and when), which
``python -m hostsim gains --params OUT.json`` accepts. Several logs of one role are
averaged (phi, alpha, tau_c), then the parameters derived.

Logs that cannot give a fit are refused with an IdentifyError naming the log and the
problem (exit status 2): not an identify log, a run that stopped early, too few samples, a
stalled motor, a motor that never reached a steady speed, no usable run-down.
"""
import argparse
import dataclasses
import datetime
import json
import math
import os
import sys
from typing import Optional

import hostsim
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

from hostsim.errors import TipbotError
from hostsim.logs import read_log
from hostsim.model.motors import DRIVER_MOTOR, ROLE_MOTOR, TABLE2, TABLE2_G
from hostsim.model.params import DEFAULT_PARAMS_PATH, MOTOR_FIELDS, MOTOR_ROLES, load_params, parse_params
from hostsim.paths import out_dir
from tipbot_fw import fields
from tipbot_fw import identify as fw_identify
from tipbot_fw.guard.plausibility import BATTERY_MAX_V, BATTERY_MIN_V

DEFAULT_OUT = out_dir("identify")
DEG = math.pi / 180.0

# Limits of a usable log.
MIN_DRIVE_ROWS = 20          # rows in the drive phase
STALL_COUNTS = 10            # fewer counts than this while driven: stalled
MIN_DRIVE_EVENTS = 40        # count changes while driven
MIN_RISE_EVENTS = 8          # count changes during the rise (the first 3 alpha)
MAX_READ_FRACTION = 0.25     # the median time between reads must be below alpha x this
STEADY_WINDOW = 0.2          # the last 20 % of the drive ...
STEADY_TOL = 0.03            # ... must run within 3 % of the speed of the 20 % before it
MIN_RUNDOWN_EVENTS = 15
MAX_DEAD_TIME_S = 0.05
GRID_S = 1e-4                # integration step of the step-response model


class IdentifyError(TipbotError):
    """A log that cannot give a fit; the message names the log and the problem."""


class NotAnIdentifyLog(IdentifyError):
    pass


# An EV3 motor at any usable duty turns many degrees in this time.
STALL_MIN_DRIVE_S = 0.1


class TooFewSamples(IdentifyError):
    pass


class MotorStalled(IdentifyError):
    pass


class NotSteady(IdentifyError):
    pass


class NoRundown(IdentifyError):
    pass


# ------------------------------------------------------------------------------ the log
class IdLog:
    """An identify log's header and columns (times in s from the drive command)."""

    def __init__(self, path, header, rows):
        self.path = path
        self.header = header
        names = [c.get("name") if isinstance(c, dict) else c for c in header.get("columns", [])]
        cols = {n: rows[:, i] for i, n in enumerate(names)}
        self.t = cols["time_s"]
        self.t_prev = cols["prev_read_s"]
        self.pos = cols["position"]
        self.phase = cols["phase"].astype(int)
        self.duty = cols["duty"]
        self.battery_v = cols["battery_v"]
        self.duty_pct = int(header["duty"])
        self.sign = 1.0 if self.duty_pct > 0 else -1.0

    @property
    def name(self):
        return os.path.basename(self.path)

    def battery_at(self, times):
        """Battery voltage in effect at the given times (the last reading logged before)."""
        i = np.searchsorted(self.t, times, side="right") - 1
        return self.battery_v[np.clip(i, 0, len(self.t) - 1)]


def load_log(path):
    """-> IdLog; IdentifyError (NotAnIdentifyLog) naming the problem."""
    header, rows, names = read_log(path, IdentifyError)
    if header.get("kind") != fw_identify.KIND:
        raise NotAnIdentifyLog("%s: not an identify log (header kind %r; a balance run log has none): record one with "
                               "`python3 -m tipbot_fw identify --port PORT` on the brick" % (path, header.get("kind")))
    missing = [n for n in fw_identify.COLUMN_NAMES if n not in names]
    if missing:
        raise NotAnIdentifyLog("%s: identify log without the column(s) %s" % (path, ", ".join(missing)))
    if header.get("stop_reason") != "completed":
        raise IdentifyError("%s: the identify run stopped early (%s: %s); record it again"
                            % (path, header.get("stop_reason"), header.get("stop_message")))
    check_content(path, header, rows, names)
    try:
        return IdLog(path, header, rows)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
        raise IdentifyError("%s: a header this version cannot interpret: %s: %s" % (path, type(e).__name__, e))


def check_content(path, header, rows, names):
    """The header's duty, finite rows, battery readings an EV3 can give, and the drive phase's
    duty column equal to the header's (IdentifyError '<log>: field <name> <problem>')."""
    f = fields.Fields(path, IdentifyError)
    duty = f.check("duty", header.get("duty"), fields.number(lo=-100, hi=100, lo_open=False, integer=True))
    if duty == 0:
        f.fail("duty", "is 0: the motor was not driven")
    bad = np.argwhere(~np.isfinite(rows))
    if len(bad):
        i, c = bad[0]
        f.fail("rows[%d].%s" % (i, names[c]), "is %r, not a finite number" % rows[i, c])
    col = {n: rows[:, i] for i, n in enumerate(names)}
    battery = col["battery_v"]
    out = np.nonzero((battery < BATTERY_MIN_V) | (battery > BATTERY_MAX_V))[0]
    if len(out):
        f.fail("rows[%d].battery_v" % out[0], "is %r V, outside what an EV3 battery reads (%g-%g V)"
               % (battery[out[0]], BATTERY_MIN_V, BATTERY_MAX_V))
    drive = col["phase"] == fw_identify.PHASE_DRIVE
    wrong = np.nonzero(drive & (col["duty"] != duty))[0]
    if len(wrong):
        f.fail("duty", "is %d, but row %d of the drive says %r: header and body disagree"
               % (duty, wrong[0], col["duty"][wrong[0]]))
    if np.any(np.diff(col["time_s"]) < 0):
        f.fail("rows.time_s", "goes backwards: not the reads of one run")


def count_events(log, phase):
    """Changes of the count within a phase (direction normalized so the drive is positive).

    -> (t_mid, y, dt, dc): the boundaries c'+1..c were passed between the read before
    (t_prev) and this one (t); at t_mid = (t_prev + t)/2 the shaft was at y = (c'+1+c)/2.
    dt = t - t_prev, dc = c - c'. Only forward changes (dc > 0)."""
    c = log.sign * log.pos
    dc = np.diff(c, prepend=c[0])
    keep = (log.phase == phase) & (dc > 0)
    t, tp = log.t[keep], log.t_prev[keep]
    return 0.5 * (t + tp), c[keep] - 0.5 * (dc[keep] - 1.0), t - tp, dc[keep]


def _fit(path, what, fun, x0, **kw):
    """scipy's least_squares, with its refusals (residuals not finite, a start outside the
    bounds) as IdentifyError naming the log."""
    try:
        return least_squares(fun, x0, **kw)
    except (ValueError, FloatingPointError) as e:
        raise IdentifyError("%s: the %s cannot be fitted: %s" % (path, what, e))


def _line(t, y):
    """Least-squares line -> (slope, intercept)."""
    a = np.vstack([t, np.ones_like(t)]).T
    return np.linalg.lstsq(a, y, rcond=None)[0]


# ------------------------------------------------------------------------------ the step
def step_position(params, log, t, t_end):
    """Model counts at times t (s from the drive command): from rest at p0, G(s) driven by
    d/100 x Vb(t) from t_d on. params = (p0, phi, alpha, t_d)."""
    p0, phi, alpha, td = params
    n = int(math.ceil(max(t_end - td, GRID_S) / GRID_S)) + 1
    s = np.arange(n) * GRID_S
    v = (abs(log.duty_pct) / 100.0) * log.battery_at(s + td)
    e = math.exp(-GRID_S / alpha)
    target = phi * v[:-1]
    w = np.empty(n)
    w[0] = 0.0
    w[1:] = lfilter([1.0 - e], [1.0, -e], target)
    inc = target * GRID_S + (w[:-1] - target) * alpha * (1.0 - e)
    theta = np.concatenate([[0.0], np.cumsum(inc)])
    return p0 + np.interp(t - td, s, theta, left=0.0) / DEG


def step_speed(params, log, t, t_end):
    """Model speed (rad/s) at times t."""
    p0, phi, alpha, td = params
    n = int(math.ceil(max(t_end - td, GRID_S) / GRID_S)) + 1
    s = np.arange(n) * GRID_S
    v = (abs(log.duty_pct) / 100.0) * log.battery_at(s + td)
    e = math.exp(-GRID_S / alpha)
    w = np.concatenate([[0.0], lfilter([1.0 - e], [1.0, -e], phi * v[:-1])])
    return np.interp(t - td, s, w, left=0.0)


def check_drive(log):
    """The usability checks that need no fit. -> (events, steady speed in rad/s)."""
    where = log.path
    drive = log.phase == fw_identify.PHASE_DRIVE
    n_rows = int(drive.sum())
    t_cmd = log.header.get("coast_command_s") or [None]
    t_drive = t_cmd[0] if t_cmd[0] is not None else (log.t[drive].max() if n_rows else 0.0)
    # A motor that did not turn during a drive long enough for any working motor to turn is
    # stalled, however few samples a slow or loaded brick took: say that, not "too few samples".
    c = log.sign * log.pos[drive]
    moved = c.max() - c.min() if n_rows else 0

    def stalled():
        return MotorStalled("%s: the motor stalled: it turned %d count(s) in %.2f s at duty %d %% (blocked, not "
                            "connected, or a duty too small to overcome friction)"
                            % (where, moved, t_drive, log.duty_pct))

    if n_rows >= 2 and t_drive >= STALL_MIN_DRIVE_S and moved < STALL_COUNTS:
        raise stalled()
    if n_rows < MIN_DRIVE_ROWS:
        raise TooFewSamples("%s: too few samples: %d rows while driven (at least %d needed): the drive was too "
                            "short or the reads too slow (--seconds, --period-ms)" % (where, n_rows, MIN_DRIVE_ROWS))
    if moved < STALL_COUNTS:
        raise stalled()
    ev = count_events(log, fw_identify.PHASE_DRIVE)
    if len(ev[0]) < MIN_DRIVE_EVENTS:
        raise TooFewSamples("%s: too few samples: the count changed %d times while driven (at least %d needed)"
                            % (where, len(ev[0]), MIN_DRIVE_EVENTS))
    still = log.phase == fw_identify.PHASE_STILL
    if still.any():
        tail = still & (log.t > log.t[still].max() - 0.1)
        if np.ptp(log.pos[tail]) > 1:
            raise IdentifyError("%s: the shaft was turning before the drive (%d counts in the last 0.1 s of "
                                "the standstill): the fit needs a start from rest" % (where, np.ptp(log.pos[tail])))
    # steady state: the last STEADY_WINDOW of the drive against the one before it
    tm, y = ev[0], ev[1]
    w = STEADY_WINDOW * t_drive
    last = tm >= t_drive - w
    before = (tm >= t_drive - 2 * w) & ~last
    if last.sum() < 5 or before.sum() < 5:
        raise TooFewSamples("%s: too few samples: %d and %d count changes in the last two %.0f %% windows of the "
                            "drive, too few to tell whether the speed was steady"
                            % (where, before.sum(), last.sum(), 100 * STEADY_WINDOW))
    s_last = _line(tm[last], y[last])[0]
    s_before = _line(tm[before], y[before])[0]
    change = (s_last - s_before) / s_last
    if abs(change) > STEADY_TOL:
        raise NotSteady("%s: the motor never reached a steady speed: over the last %.0f %% of the %.2f s drive it ran "
                        "%+.1f %% faster than over the %.0f %% before (tolerance %.0f %%); drive longer (--seconds)"
                        % (where, 100 * STEADY_WINDOW, t_drive, 100 * change, 100 * STEADY_WINDOW, 100 * STEADY_TOL))
    return ev, s_last * DEG


def _weights(ev, speed_counts_s, floor_counts=0.1):
    """1/sigma of each event: the time between the two reads makes its position uncertain."""
    _, _, dt, dc = ev
    sigma = np.sqrt((speed_counts_s * dt) ** 2 / 12.0 + (dc - 1.0) ** 2 / 12.0 + floor_counts ** 2)
    return 1.0 / sigma


def fit_step(log, dead_time=True):
    """Fit (p0, phi, alpha, t_d) to the drive phase. -> dict."""
    ev, speed = check_drive(log)
    tm, y = ev[0], ev[1]
    drive = log.phase == fw_identify.PHASE_DRIVE
    t_end = float(log.t[drive].max())
    v_ss = (abs(log.duty_pct) / 100.0) * float(np.mean(log.battery_at(tm[tm > 0.5 * t_end])))
    # start: the steady asymptote y = y0 + S (t - (t_d + alpha))
    c0 = float(log.sign * log.pos[drive][0])
    late = tm > 0.5 * t_end
    slope, icpt = _line(tm[late], y[late])
    lag = max((c0 - icpt) / slope, 1e-3)
    x0 = [c0, slope * DEG / v_ss, lag, 0.0]
    wts = _weights(ev, slope)

    def resid(x):
        return (step_position(x, log, tm, t_end) - y) * wts

    lo = [-np.inf, 1e-6, 1e-4, 0.0]
    hi = [np.inf, np.inf, 10.0, MAX_DEAD_TIME_S if dead_time else 1e-12]
    x0[3] = min(x0[3], hi[3])
    sol = _fit(log.path, "step response", resid, x0, bounds=(lo, hi), x_scale=[1.0, 0.1, 0.01, 0.001])
    p0, phi, alpha, td = sol.x
    rms = float(np.sqrt(np.mean((step_position(sol.x, log, tm, t_end) - y) ** 2)))
    # resolution of the rise
    rise = (tm > td) & (tm < td + 3 * alpha)
    dts = log.t[drive][1:] - log.t_prev[drive][1:]
    read_s = float(np.median(dts)) if len(dts) else float("nan")
    if rise.sum() < MIN_RISE_EVENTS:
        raise TooFewSamples("%s: too few samples: the count changed only %d times during the rise (3 alpha = %.1f ms), "
                            "at least %d needed" % (log.path, rise.sum(), 3e3 * alpha, MIN_RISE_EVENTS))
    if read_s > MAX_READ_FRACTION * alpha:
        raise TooFewSamples("%s: too few samples: reads every %.2f ms, too slow for a time constant of %.1f ms "
                            "(at most %.2f ms); read faster (--period-ms 0)"
                            % (log.path, 1e3 * read_s, 1e3 * alpha, 1e3 * MAX_READ_FRACTION * alpha))
    return dict(params=sol.x, p0=p0, phi=phi, alpha=alpha, dead_time_s=td, rms_counts=rms, events=len(tm),
                rise_events=int(rise.sum()), read_period_s=read_s, v_steady=v_ss, steady_speed=speed,
                t_end=t_end, data=(tm, y))


# ------------------------------------------------------------------------------ the run-down
def rundown_position(x, t):
    """theta(t) in counts for omega' = -(omega + c)/tau from omega_c at t = 0, held at the stop."""
    th_c, w_c, tau, c = x
    if c <= 0.0:
        return th_c + w_c * tau * (1.0 - np.exp(-t / tau))
    t_stop = tau * math.log((w_c + c) / c)
    tt = np.minimum(t, t_stop)
    return th_c + (w_c + c) * tau * (1.0 - np.exp(-tt / tau)) - c * tt


def fit_rundown(log, step):
    """Fit the coasting run-down: viscous (c = 0), and with Coulomb friction. -> dict."""
    where = log.path
    ev = count_events(log, fw_identify.PHASE_COAST)
    tc = float(np.mean(log.header.get("coast_command_s") or [step["t_end"]]))
    tm, y = ev[0] - tc, ev[1]
    if len(tm) < MIN_RUNDOWN_EVENTS:
        raise NoRundown("%s: no usable run-down: the count changed %d times after the coast command (at least %d "
                        "needed; was the stop action brake, or the run-down cut short?)" % (where, len(tm), MIN_RUNDOWN_EVENTS))
    w_c = step["steady_speed"] / DEG          # counts/s
    wts = _weights(ev, w_c)
    th0 = y[0] - w_c * tm[0]
    span = tm[-1]
    x0 = [th0, w_c, max(span / 2.0, 0.01), 0.0]

    def fit(x_start, coulomb):
        lo = [-np.inf, 0.1 * w_c, 1e-3, 0.0]
        hi = [np.inf, 10.0 * w_c, 1e3, 10.0 * w_c if coulomb else 1e-9]
        x_start = np.clip(x_start, lo, [h if np.isfinite(h) else np.inf for h in hi])
        sol = _fit(where, "run-down", lambda x: (rundown_position(x, tm) - y) * wts, x_start, bounds=(lo, hi),
                   x_scale=[1.0, 0.1 * w_c, 0.1, 0.1 * w_c])
        return sol.x, float(np.sqrt(np.mean((rundown_position(sol.x, tm) - y) ** 2)))

    xv, rms_v = fit(x0, False)
    xc, rms_c = fit(np.array(list(xv[:3]) + [0.1 * w_c]), True)
    tau_c = float(xv[2])
    if tau_c >= 1e3 * 0.999:
        raise NoRundown("%s: no usable run-down: the speed did not fall after the coast command" % where)
    coulomb_speed = float(xc[3])
    dominated = coulomb_speed > xc[1]
    return dict(tau_c=tau_c, omega_c=float(xv[1]) * DEG, rms_counts=rms_v, events=len(tm), t_coast=tc,
                x_viscous=xv, x_coulomb=xc, rms_coulomb=rms_c, coulomb_speed=coulomb_speed * DEG,
                tau_with_coulomb=float(xc[2]), coulomb_dominated=bool(dominated), ended=log.header.get("rundown_end"),
                data=(tm, y))


def fit_log(log, dead_time=True):
    """Step and run-down fits of one log -> dict (adds the log)."""
    if isinstance(log, str):
        log = load_log(log)
    step = fit_step(log, dead_time)
    rd = fit_rundown(log, step)
    r = step["alpha"] / rd["tau_c"]
    if r >= 1.0:
        raise IdentifyError("%s: inconsistent: the run-down (tau_c %.4g s) decays faster than the driven rise "
                            "(alpha %.4g s); coasting must be an open circuit (stop_action coast)"
                            % (log.path, rd["tau_c"], step["alpha"]))
    return dict(log=log, step=step, rundown=rd)


# ------------------------------------------------------------------------------ parameters
def derive(phi, alpha, tau_c, ra_ohm, jm_kg_m2=None, load_inertia_kg_m2=0.0):
    """Motor parameters from the three measured quantities (module docstring). -> dict.

    jm_kg_m2 None: assume Km = Ke. load_inertia_kg_m2 is subtracted from the inertia found
    (a wheel on the shaft); beta stays the whole shaft's (the load's bearing included)."""
    r = alpha / tau_c
    ke = (1.0 - r) / phi
    if jm_kg_m2 is None:
        km = ke
        j_total = km * alpha / (phi * ra_ohm)
        assumption = "Km = Ke"
    else:
        j_total = jm_kg_m2 + load_inertia_kg_m2
        km = phi * ra_ohm * j_total / alpha
        assumption = "Jm given"
    beta = j_total / tau_c
    jm = j_total - load_inertia_kg_m2
    if jm <= 0:
        raise IdentifyError("the load inertia %.4g kg m^2 is not smaller than the inertia found, %.4g kg m^2"
                            % (load_inertia_kg_m2, j_total))
    return dict(beta_nm_s=beta, ke_v_s=ke, km_nm_a=km, ra_ohm=ra_ohm, jm_kg_m2=jm, j_total_kg_m2=j_total,
                friction_share=r, assumption=assumption)


def model_g(p):
    """(phi, alpha, tau_c) of a parameter dict (Section 4's formulas)."""
    den = p["ra_ohm"] * p["beta_nm_s"] + p["ke_v_s"] * p["km_nm_a"]
    j = p.get("j_total_kg_m2", p["jm_kg_m2"])
    return p["km_nm_a"] / den, p["ra_ohm"] * j / den, j / p["beta_nm_s"]


def role_of(log, role=None):
    return role or log.header.get("role")


def table2_motor(log, role):
    if role in ROLE_MOTOR:
        return ROLE_MOTOR[role]
    return DRIVER_MOTOR.get(log.header.get("driver"), 1)


# ------------------------------------------------------------------------------ reporting
def describe_fit(f):
    log, s, rd = f["log"], f["step"], f["rundown"]
    h = log.header
    role = f.get("role", h.get("role"))
    lines = ["%s: port %s, %s, role %s, duty %d %%, battery %.2f V at start, %.2f V at the end"
             % (log.path, h.get("port"), h.get("driver"), role or "-", log.duty_pct,
                h.get("battery_v_start", float("nan")), h.get("battery_v_end", float("nan"))),
             "  %d reads while driven (one per %.1f us on average, %.1f us around a count change), "
             "%d count changes (%d during the rise)"
             % (h.get("reads", {}).get("drive", 0), 1e6 * h.get("read_period_s", {}).get("drive", float("nan")),
                1e6 * s["read_period_s"], s["events"], s["rise_events"]),
             "  step:     phi %.4f rad/s/V, alpha %.4f s, dead time %.2f ms; steady %.2f rad/s at %.2f V; "
             "fit rms %.2f counts" % (s["phi"], s["alpha"], 1e3 * s["dead_time_s"], s["steady_speed"], s["v_steady"],
                                      s["rms_counts"]),
             "  run-down: tau_c = Jm/beta %.4f s from %.2f rad/s (viscous fit rms %.2f counts, %d changes, ended: %s)"
             % (rd["tau_c"], rd["omega_c"], rd["rms_counts"], rd["events"], rd["ended"])]
    if role == h.get("role") and h.get("expected_driver") and h.get("expected_driver") != h.get("driver"):
        lines.append("  NOTE: the configuration expects a %s for %s, the log has a %s: give --role if that is "
                     "not the motor's role" % (h.get("expected_driver"), role, h.get("driver")))
    if rd["coulomb_dominated"]:
        lines.append("  NOTE: the run-down looks Coulomb-dominated (the speed falls about linearly: with Coulomb "
                     "friction, tau %.3f s and Coulomb friction outweighing the viscous one below %.1f rad/s, "
                     "above the %.1f rad/s at the coast command); the model has viscous friction only, so "
                     "tau_c, beta and Jm are a rough equivalent" % (rd["tau_with_coulomb"], rd["coulomb_speed"],
                                                                    rd["omega_c"]))
    elif rd["coulomb_speed"] > 0.05 * rd["omega_c"]:
        lines.append("  run-down with Coulomb friction: tau %.3f s, Coulomb outweighs viscous below %.2f rad/s "
                     "(rms %.2f counts); the model keeps the viscous fit" % (rd["tau_with_coulomb"], rd["coulomb_speed"],
                                                                             rd["rms_coulomb"]))
    return "\n".join(lines)


def table(group, load_j):
    """An IdentifiedGroup's values beside Table 2's motor."""
    role, motor, fits, p, ra_source = group.role, group.table2_motor, group.fits, group.params, group.ra_source
    t2 = TABLE2[motor]
    g_phi, g_alpha = TABLE2_G[motor]
    phi = np.array([f["step"]["phi"] for f in fits])
    alpha = np.array([f["step"]["alpha"] for f in fits])
    tau = np.array([f["rundown"]["tau_c"] for f in fits])
    spread = (lambda a: "" if len(a) < 2 else " +-%.2g%%" % (100 * np.std(a) / np.mean(a)))
    rows = [
        ("phi", "rad/s/V", phi.mean(), t2.phi, "G(s) gain" + spread(phi) + "; printed %.4g" % g_phi),
        ("alpha", "s", alpha.mean(), t2.alpha, "G(s) time constant" + spread(alpha) + "; printed %.4g" % g_alpha),
        ("tau_c", "s", tau.mean(), t2.tau_coast_s, "run-down, Jm/beta" + spread(tau)),
        ("Ke", "V s/rad", p["ke_v_s"], t2.ke_v_s, "(1 - alpha/tau_c)/phi"),
        ("Km", "N m/A", p["km_nm_a"], t2.km_nm_a, "assumed = Ke" if p["assumption"] == "Km = Ke"
         else "phi Ra Jm/alpha (Jm given)"),
        ("Ra", "ohm", p["ra_ohm"], t2.ra_ohm, ra_source),
        ("beta", "N m s", p["beta_nm_s"], t2.beta_nm_s, "Jm/tau_c"),
        ("Jm", "kg m^2", p["jm_kg_m2"], t2.jm_kg_m2, ("Km alpha/(phi Ra)" if p["assumption"] == "Km = Ke" else "given")
         + (" - load %.3g" % load_j if load_j else "")),
    ]
    out = ["%s (%d log%s) beside Table 2 motor %d:" % (role or "motor", len(fits), "s" if len(fits) > 1 else "", motor),
           "  %-6s %-8s %12s %12s %7s  %s" % ("", "unit", "identified", "Table 2", "ratio", "how")]
    for name, unit, mine, paper, how in rows:
        out.append("  %-6s %-8s %12.5g %12.5g %7.3f  %s" % (name, unit, mine, paper, mine / paper, how))
    return "\n".join(out)


def assumptions_text(p, ra_sources, load_j):
    lines = ["assumptions: ideal DC motor, inductance neglected, viscous friction only; coasting = open circuit; "
             "voltage = duty x battery voltage (the driver's drop counts in Ra); the shaft turned freely",
             "  Ra (not measurable by this test): %s" % "; ".join(ra_sources)]
    if p["assumption"] == "Km = Ke":
        lines.append("  Km = Ke (SI, ideal motor): a step and a run-down determine Ke, Km/Jm and beta/Jm only; "
                     "Table 2's Ke/Km = %.2f (motor 1) would show here as Jm and beta scaled by that ratio"
                     % (TABLE2[1].ke_v_s / TABLE2[1].km_nm_a))
    else:
        lines.append("  Jm given (--jm-kg-m2): Km from phi Ra Jm / alpha, independent of Ke")
    if load_j:
        lines.append("  Jm: the inertia found minus the load on the shaft, %.4g kg m^2" % load_j)
    return "\n".join(lines)


def plot(fits, path):
    """Measured and fitted speed against time, one panel per log (Figure 3's layout)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(fits)
    cols = min(n, 2)
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 3.6 * rows), squeeze=False)
    for ax, f in zip(axes.flat, fits):
        log, s, rd = f["log"], f["step"], f["rundown"]
        t_m, w_m = measured_speed(log)
        ax.plot(t_m, w_m, ".", ms=2, color="0.55", label="measured (encoder)")
        t_d = np.linspace(0.0, s["t_end"], 4000)
        ax.plot(t_d, step_speed(s["params"], log, t_d, s["t_end"]), "C0", lw=1.6,
                label="fit: %.3f/(%.4f s + 1)" % (s["phi"], s["alpha"]))
        t_r = np.linspace(0.0, rd["data"][0][-1], 400)
        th, w0, tau, _ = rd["x_viscous"]
        ax.plot(rd["t_coast"] + t_r, w0 * np.exp(-t_r / tau) * DEG, "C1", lw=1.6,
                label="run-down fit: tau_c %.3f s" % tau)
        motor = table2_motor(log, log.header.get("role"))
        tp = TABLE2[motor]
        v = (abs(log.duty_pct) / 100.0) * log.battery_at(t_d)
        w_paper = lfilter([1 - math.exp(-(t_d[1] - t_d[0]) / tp.alpha)], [1, -math.exp(-(t_d[1] - t_d[0]) / tp.alpha)],
                          tp.phi * v)
        ax.plot(t_d, w_paper, "k--", lw=0.9, label="Table 2 motor %d" % motor)
        # the rise, enlarged
        ins = ax.inset_axes([0.13, 0.1, 0.22, 0.5])
        t_z = np.linspace(0.0, 5 * s["alpha"] + s["dead_time_s"], 300)
        t_mz, w_mz = measured_speed(log, window_s=min(0.02, s["alpha"] / 4))
        z = t_mz < t_z[-1]
        ins.plot(t_mz[z] * 1e3, w_mz[z], ".", ms=2, color="0.55")
        ins.plot(t_z * 1e3, step_speed(s["params"], log, t_z, s["t_end"]), "C0", lw=1.2)
        ins.plot(t_z * 1e3, np.interp(t_z, t_d, w_paper), "k--", lw=0.8)
        ins.set_xlabel("ms", fontsize=6, labelpad=0)
        ins.tick_params(labelsize=6)
        ins.grid(alpha=0.3)
        ax.set_title("%s: %s on %s" % (log.name, log.header.get("driver"), log.header.get("port")), fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("speed [rad/s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle("Motor real-time response (measured and fitted, cf. Figure 3)", fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def measured_speed(log, window_s=0.02):
    """Speed (rad/s) from the count changes, over windows of window_s (for plots)."""
    out_t, out_w = [], []
    for phase in (fw_identify.PHASE_DRIVE, fw_identify.PHASE_COAST):
        tm, y, _, _ = count_events(log, phase)
        if len(tm) < 2:
            continue
        j = np.searchsorted(tm, tm + window_s)
        ok = j < len(tm)
        i, j = np.nonzero(ok)[0], j[ok]
        good = j > i
        i, j = i[good], j[good]
        out_t.append(0.5 * (tm[i] + tm[j]))
        out_w.append((y[j] - y[i]) / (tm[j] - tm[i]) * DEG)
    if not out_t:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(out_t), np.concatenate(out_w)


# ------------------------------------------------------------------------------ parameters file
def write_params(base_path, out_path, derived, sources):
    """A copy of the parameters file at base_path with the roles' motor fields replaced.
    derived: {role: parameter dict}; sources: {role: text}. The top-level object
    ``identified`` keeps, per role, what the fit measured (hostsim.model.params ignores it).
    Validated before it is written; out_path may be base_path."""
    with open(base_path) as f:
        doc = json.load(f)
    record = doc.setdefault("identified", {})
    for role, p in derived.items():
        for field in MOTOR_FIELDS:
            key = "%s_%s" % (role, field)
            doc["parameters"][key] = {"value": float("%.6g" % p[field]),
                                      "source": "%s: %s" % (sources[role], FIELD_HOW[field](p))}
        record[role] = {"source": sources[role], "phi_rad_s_v": p["phi"], "alpha_s": p["alpha"],
                        "tau_c_s": p["tau_c"], "assumption": p["assumption"], "ra_source": p["ra_source"],
                        "load_inertia_kg_m2": p["load_inertia_kg_m2"], "tool": "python -m hostsim identify"}
    parse_params(doc, out_path)
    tmp = out_path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, out_path)
    return out_path


FIELD_HOW = {
    "beta_nm_s": lambda p: "beta = Jm/tau_c (viscous run-down)",
    "ke_v_s": lambda p: "Ke = (1 - alpha/tau_c)/phi",
    "km_nm_a": lambda p: "Km = Ke (assumed)" if p["assumption"] == "Km = Ke" else "Km = phi Ra Jm/alpha (Jm given)",
    "ra_ohm": lambda p: "Ra " + p["ra_source"],
    "jm_kg_m2": lambda p: ("Jm = Km alpha/(phi Ra)" if p["assumption"] == "Km = Ke" else "Jm given")
    + (" minus the load %.4g" % p["load_inertia_kg_m2"] if p["load_inertia_kg_m2"] else ""),
}


# ------------------------------------------------------------------------------ command line
@dataclasses.dataclass(frozen=True)
class IdentifiedGroup:
    """The logs of one role (or one unnamed log) and the parameters derived from their mean fit."""
    role: Optional[str]          # None: the log named no role and none was given
    table2_motor: int            # the paper's motor to compare with
    fits: list                   # fit_log() of each log
    params: dict                 # derive() + phi, alpha, tau_c, ra_source, load_inertia_kg_m2
    ra_source: str               # where Ra came from


def identify(paths, roles=(), ra_ohm=None, jm_kg_m2=None, load_inertia_kg_m2=0.0, params_path=DEFAULT_PARAMS_PATH,
             dead_time=True):
    """Fit every log, group by role, derive. -> (fits, [IdentifiedGroup])."""
    if roles and len(roles) not in (1, len(paths)):
        raise IdentifyError("--role given %d times for %d logs: give it once (all logs) or once per log"
                            % (len(roles), len(paths)))
    base = load_params(params_path)
    fits = []
    for i, path in enumerate(paths):
        log = load_log(path)
        role = role_of(log, roles[0] if len(roles) == 1 else (roles[i] if roles else None))
        if role is not None and role not in MOTOR_ROLES:
            raise IdentifyError("%s: role %r is not one of %s" % (path, role, ", ".join(MOTOR_ROLES)))
        f = fit_log(log, dead_time)
        f["role"] = role
        fits.append(f)
    groups = []
    order = []
    for f in fits:
        key = f["role"] or ("<%s>" % f["log"].path)
        if key not in order:
            order.append(key)
    for key in order:
        members = [f for f in fits if (f["role"] or ("<%s>" % f["log"].path)) == key]
        role = members[0]["role"]
        if ra_ohm is not None:
            ra, ra_source = ra_ohm, "given (--ra-ohm %g)" % ra_ohm
        elif role is not None:
            ra, ra_source = base["%s_ra_ohm" % role], "from %s (%s_ra_ohm)" % (os.path.relpath(params_path), role)
        else:
            motor = table2_motor(members[0]["log"], None)
            ra, ra_source = TABLE2[motor].ra_ohm, "Table 2 motor %d (no role: give --role or --ra-ohm)" % motor
        phi = float(np.mean([f["step"]["phi"] for f in members]))
        alpha = float(np.mean([f["step"]["alpha"] for f in members]))
        tau = float(np.mean([f["rundown"]["tau_c"] for f in members]))
        p = derive(phi, alpha, tau, ra, jm_kg_m2, load_inertia_kg_m2)
        p.update(ra_source=ra_source, load_inertia_kg_m2=load_inertia_kg_m2, phi=phi, alpha=alpha, tau_c=tau)
        groups.append(IdentifiedGroup(role, table2_motor(members[0]["log"], role), members, p, ra_source))
    return fits, groups


def summary_json(groups):
    out = {}
    for g in groups:
        members, p = g.fits, g.params
        out[g.role or members[0]["log"].path] = {
            "logs": [f["log"].path for f in members],
            "table2_motor": g.table2_motor,
            "fits": [{"phi": f["step"]["phi"], "alpha": f["step"]["alpha"], "dead_time_s": f["step"]["dead_time_s"],
                      "tau_c": f["rundown"]["tau_c"], "step_rms_counts": f["step"]["rms_counts"],
                      "rundown_rms_counts": f["rundown"]["rms_counts"],
                      "coulomb_dominated": f["rundown"]["coulomb_dominated"]} for f in members],
            "parameters": {k: p[k] for k in MOTOR_FIELDS},
            "assumption": p["assumption"], "ra_source": g.ra_source, "friction_share": p["friction_share"],
        }
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("identify"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", metavar="LOG", help="identify logs (python3 -m tipbot_fw identify)")
    ap.add_argument("--role", action="append", default=[], choices=MOTOR_ROLES,
                    help="the motor's role (default: the log's, from the brick's config); once for all logs or once per log")
    ap.add_argument("--ra-ohm", type=float, help="armature resistance measured at the motor's terminals "
                    "(default: the role's value in --params)")
    ap.add_argument("--jm-kg-m2", type=float, help="a known inertia instead of assuming Km = Ke")
    ap.add_argument("--load-inertia-kg-m2", type=float, default=0.0,
                    help="inertia turning with the shaft that is not the motor's (e.g. a wheel left on: Jw)")
    ap.add_argument("--no-dead-time", action="store_true", help="fit without a dead time")
    ap.add_argument("--params", default=DEFAULT_PARAMS_PATH, help="parameters file (Ra, and the base of --write-params)")
    ap.add_argument("--write-params", metavar="OUT.json", help="write --params with the identified roles replaced")
    ap.add_argument("--out", metavar="DIR", default=DEFAULT_OUT, help="plot and summary directory (default out/identify)")
    ap.add_argument("--no-plots", action="store_true", help="print the fits only (no PNG, no identify.json)")
    a = ap.parse_args(argv)
    for name in ("ra_ohm", "jm_kg_m2"):
        v = getattr(a, name)
        if v is not None and not (v > 0 and math.isfinite(v)):
            ap.error("--%s must be a positive number" % name.replace("_", "-"))
    if not (a.load_inertia_kg_m2 >= 0):
        ap.error("--load-inertia-kg-m2 must not be negative")
    try:
        fits, groups = identify(a.logs, a.role, a.ra_ohm, a.jm_kg_m2, a.load_inertia_kg_m2, a.params,
                                not a.no_dead_time)
        for f in fits:
            print(describe_fit(f))
        print()
        for g in groups:
            print(table(g, a.load_inertia_kg_m2))
            phi_m, alpha_m, _ = model_g(g.params)
            print("  check: the derived parameters give phi %.5g, alpha %.5g (Section 4's formulas)" % (phi_m, alpha_m))
            print()
        print(assumptions_text(groups[0].params, ["%s %s" % (g.role or "motor", g.ra_source) for g in groups],
                               a.load_inertia_kg_m2))
        if a.write_params:
            unnamed = [g.fits[0]["log"].path for g in groups if g.role is None]
            if unnamed:
                raise IdentifyError("%s: no role for --write-params (the log has none): give --role" % unnamed[0])
            today = datetime.date.today().isoformat()
            sources = {g.role: "identified from %s on %s" % (", ".join(os.path.basename(f["log"].path) for f in g.fits),
                                                              today) for g in groups}
            write_params(a.params, a.write_params, {g.role: g.params for g in groups}, sources)
            print("wrote %s (roles %s); next: python -m hostsim gains --params %s"
                  % (a.write_params, ", ".join(g.role for g in groups), a.write_params))
        if not a.no_plots:
            os.makedirs(a.out, exist_ok=True)
            png = plot(fits, os.path.join(a.out, "identify.png"))
            with open(os.path.join(a.out, "identify.json"), "w") as f:
                json.dump(summary_json(groups), f, indent=1, sort_keys=True)
            print("plot %s, summary %s" % (os.path.relpath(png), os.path.relpath(os.path.join(a.out, "identify.json"))))
    except TipbotError as e:
        sys.stderr.write("identify: error: %s\n" % e)
        return 2
    return 0

