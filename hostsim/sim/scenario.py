"""Simulation scenarios as data files (JSON), validated field by field.

A scenario says what to simulate, not how: initial state and estimate (SI: m, rad, m/s,
rad/s, in ``x0_si``/``xhat0_si``; or as the paper prints them, d and d' in cm and cm/s, in
``x0_paper_units``/``xhat0_paper_units``), the input disturbance schedule (volts on
[u_r, u_l, -, u_th2, u_th3]), duration, which gains file and controllers, the plant variant
and parameter perturbations, sensor imperfections, extra delay, loop jitter. Unknown or
malformed fields are errors naming the field.

Each scenario runs in one or more ``modes`` (hostsim.runner):

- ``linear``: the paper's simulation, the discrete linear model with the detector and the
  control law, ideal full-state measurement (y = x), saturation at u_max_v. The plant is
  the gains file's (A, B), or the linearization of ``plant_variant`` with ``param_scale``
  when they differ from the gains' model. Sensor fields and jitter do not apply.
- ``nonlinear``: the same host-side detector and law on the nonlinear plant (1 kHz, the
  input held over each tick), still with y = x: what the model's nonlinearity and the
  saturation do, without the firmware's signal chain.
- ``firmware``: the unmodified firmware (tipbot_fw) against the nonlinear plant and the
  sensor models (hostsim.fil). Its estimate starts from the first measurement, as on the
  robot (``xhat0`` does not apply), and its wheel-position origin is where the wheels stand
  at start (see hostsim.fil).

``controllers``: ``optimal`` (LQR + detector + K_w) and/or ``pd`` (the Appendix D
baseline of hostsim.pd); each mode runs once per controller.
"""
import math
import os

from hostsim.errors import TipbotError, read_json
from hostsim.model.params import REQUIRED
from hostsim.paths import REPO_ROOT

SCENARIO_DIR = os.path.join(REPO_ROOT, "scenarios")


class ScenarioError(TipbotError):
    """A scenario file is malformed; the message names the file and the field."""


DEFAULTS = {
    "description": "",
    "duration_s": 10.0,
    "gains": "gains/physical.json",
    "controllers": ["optimal"],       # "optimal" (LQR + detector + K_w) and/or "pd" (baseline)
    "plant_variant": "physical",
    "plant_method": "heun",           # integrator of the nonlinear plant at 1 kHz (hostsim.plant)
    "param_scale": {},                # parameter name -> multiplier
    "x0_si": None,                    # initial state, SI; default zeros
    "x0_paper_units": None,           # or: initial state with d, d' in cm, cm/s (as printed)
    "xhat0_si": None,                 # initial estimate (linear, nonlinear); None: equal to x0
    "xhat0_paper_units": None,
    "disturbances": [],               # [{"t_start_s", "t_end_s", "w_v": [5]}]
    "pushes": [],                     # [{"t_s", "th1_dot_rad_s"}]: an impulse on link 1
    "sensors": {},                    # see SENSOR_DEFAULTS
    "extra_delay_ticks": 0,
    "io_latency_s": 0.002,            # firmware: tick start to its duties taking effect
    "jitter_s": 0.0,                  # std of the loop's wake-up jitter (firmware in the loop)
    "seed": 0,
    "modes": ["linear", "firmware"],  # which simulations to run (MODES)
    "settle_band_rad": 0.02,          # |th1| band for the settling time
    "expect": {},                     # optional pass criteria checked by `hostsim run`
}
SENSOR_DEFAULTS = {
    "gyro_bias_dps": 0.0,
    "gyro_noise_dps": 0.0,
    "gyro_sign": 1,
    "battery_v": 8.0,
}
# expect: {"<mode>/<controller>": {key: bound}}; every bound is an upper limit except upright.
EXPECT_KEYS = ("max_abs_th1_rad", "max_abs_th2_rad", "max_abs_th3_rad", "settle_time_s", "max_abs_u_v",
               "final_abs_d_m", "final_est_error", "upright")
MODES = ("linear", "nonlinear", "firmware")
CONTROLLERS = ("optimal", "pd")
PLANT_METHODS = ("rk4", "heun")
PAPER_TO_SI = (0.01, 0.01, 1.0, 1.0, 1.0, 0.01, 0.01, 1.0, 1.0, 1.0)


def _number(src, field, value, positive=False, non_negative=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError("%s: field '%s' must be a finite number, got %r" % (src, field, value))
    if positive and value <= 0:
        raise ScenarioError("%s: field '%s' must be positive, got %r" % (src, field, value))
    if non_negative and value < 0:
        raise ScenarioError("%s: field '%s' must not be negative, got %r" % (src, field, value))
    return float(value)


def _vector(src, field, value, length):
    if not isinstance(value, list) or len(value) != length:
        raise ScenarioError("%s: field '%s' must be a list of %d numbers" % (src, field, length))
    return [_number(src, "%s[%d]" % (field, i), v) for i, v in enumerate(value)]


def parse_scenario(doc, src="<scenario>"):
    """Validate a scenario document and fill in defaults; returns a new dict."""
    if not isinstance(doc, dict):
        raise ScenarioError("%s: a scenario is a JSON object" % src)
    unknown = sorted(set(doc) - set(DEFAULTS) - {"name"})
    if unknown:
        raise ScenarioError("%s: unknown field '%s'" % (src, unknown[0]))
    sc = dict(DEFAULTS)
    sc.update(doc)
    sc["name"] = str(doc.get("name") or os.path.splitext(os.path.basename(src))[0])
    if not isinstance(sc["description"], str):
        raise ScenarioError("%s: field 'description' must be a string" % src)
    sc["duration_s"] = _number(src, "duration_s", sc["duration_s"], positive=True)
    _choices(src, "controllers", sc["controllers"], CONTROLLERS)
    _choices(src, "modes", sc["modes"], MODES)
    if sc["plant_variant"] not in ("paper", "physical"):
        raise ScenarioError("%s: field 'plant_variant' must be 'paper' or 'physical'" % src)
    if sc["plant_method"] not in PLANT_METHODS:
        raise ScenarioError("%s: field 'plant_method' must be one of %s" % (src, ", ".join(PLANT_METHODS)))
    if not isinstance(sc["gains"], str):
        raise ScenarioError("%s: field 'gains' must be a path" % src)
    if not isinstance(sc["param_scale"], dict):
        raise ScenarioError("%s: field 'param_scale' must be an object" % src)
    for name, factor in sc["param_scale"].items():
        if name not in REQUIRED:
            raise ScenarioError("%s: field 'param_scale' names unknown parameter '%s'" % (src, name))
        _number(src, "param_scale.%s" % name, factor, positive=True)
    sc["x0_si"] = _state(src, sc, "x0") or [0.0] * 10
    sc["xhat0_si"] = _state(src, sc, "xhat0")
    del sc["x0_paper_units"], sc["xhat0_paper_units"]
    if not isinstance(sc["disturbances"], list):
        raise ScenarioError("%s: field 'disturbances' must be a list" % src)
    for i, d in enumerate(sc["disturbances"]):
        f = "disturbances[%d]" % i
        if not isinstance(d, dict) or set(d) != {"t_start_s", "t_end_s", "w_v"}:
            raise ScenarioError("%s: field '%s' needs exactly t_start_s, t_end_s, w_v" % (src, f))
        t0 = _number(src, f + ".t_start_s", d["t_start_s"], non_negative=True)
        t1 = _number(src, f + ".t_end_s", d["t_end_s"], non_negative=True)
        if t1 < t0:
            raise ScenarioError("%s: field '%s' ends before it starts" % (src, f))
        w = _vector(src, f + ".w_v", d["w_v"], 5)
        if w[2] != 0.0:
            raise ScenarioError("%s: field '%s.w_v[2]' must be 0 (link 1 has no motor)" % (src, f))
    if not isinstance(sc["pushes"], list):
        raise ScenarioError("%s: field 'pushes' must be a list" % src)
    for i, p in enumerate(sc["pushes"]):
        f = "pushes[%d]" % i
        if not isinstance(p, dict) or set(p) != {"t_s", "th1_dot_rad_s"}:
            raise ScenarioError("%s: field '%s' needs exactly t_s and th1_dot_rad_s" % (src, f))
        _number(src, f + ".t_s", p["t_s"], non_negative=True)
        _number(src, f + ".th1_dot_rad_s", p["th1_dot_rad_s"])
    if not isinstance(sc["sensors"], dict):
        raise ScenarioError("%s: field 'sensors' must be an object" % src)
    bad = sorted(set(sc["sensors"]) - set(SENSOR_DEFAULTS))
    if bad:
        raise ScenarioError("%s: unknown field 'sensors.%s'" % (src, bad[0]))
    sensors = dict(SENSOR_DEFAULTS)
    sensors.update(sc["sensors"])
    for k, v in sensors.items():
        _number(src, "sensors." + k, v, positive=(k == "battery_v"), non_negative=k.endswith("noise_dps"))
    if sensors["gyro_sign"] not in (1, -1):
        raise ScenarioError("%s: field 'sensors.gyro_sign' must be 1 or -1" % src)
    sc["sensors"] = sensors
    delay = sc["extra_delay_ticks"]
    if isinstance(delay, bool) or not isinstance(delay, int) or delay < 0:
        raise ScenarioError("%s: field 'extra_delay_ticks' must be a non-negative integer" % src)
    sc["jitter_s"] = _number(src, "jitter_s", sc["jitter_s"], non_negative=True)
    sc["io_latency_s"] = _number(src, "io_latency_s", sc["io_latency_s"], non_negative=True)
    sc["settle_band_rad"] = _number(src, "settle_band_rad", sc["settle_band_rad"], positive=True)
    if isinstance(sc["seed"], bool) or not isinstance(sc["seed"], int):
        raise ScenarioError("%s: field 'seed' must be an integer" % src)
    if not isinstance(sc["expect"], dict):
        raise ScenarioError("%s: field 'expect' must be an object" % src)
    runs = {"%s/%s" % (m, c) for m in sc["modes"] for c in sc["controllers"]}
    for label, bounds in sc["expect"].items():
        f = "expect.%s" % label
        if label not in runs:
            raise ScenarioError("%s: field '%s' names no run of this scenario (runs: %s)" % (src, f, ", ".join(sorted(runs))))
        if not isinstance(bounds, dict):
            raise ScenarioError("%s: field '%s' must be an object" % (src, f))
        for k, v in bounds.items():
            if k not in EXPECT_KEYS:
                raise ScenarioError("%s: unknown field '%s.%s'" % (src, f, k))
            if k == "upright":
                if not isinstance(v, bool):
                    raise ScenarioError("%s: field '%s.upright' must be true or false" % (src, f))
            else:
                _number(src, "%s.%s" % (f, k), v, positive=True)
    return sc


def _choices(src, field, value, allowed):
    if not isinstance(value, list) or not value or any(not isinstance(v, str) or v not in allowed for v in value):
        raise ScenarioError("%s: field '%s' must be a non-empty list of %s" % (src, field, ", ".join(allowed)))
    if len(set(value)) != len(value):
        raise ScenarioError("%s: field '%s' lists an entry twice" % (src, field))


def _state(src, sc, base):
    """x0 / xhat0 from either its SI field or its paper-units field (not both), in SI."""
    si, paper = sc[base + "_si"], sc[base + "_paper_units"]
    if si is not None and paper is not None:
        raise ScenarioError("%s: field '%s_paper_units' conflicts with '%s_si': give one" % (src, base, base))
    if si is not None:
        return _vector(src, base + "_si", si, 10)
    if paper is not None:
        return [v * k for v, k in zip(_vector(src, base + "_paper_units", paper, 10), PAPER_TO_SI)]
    return None


def load_scenario(path):
    """Read a scenario file (a path, or a name under scenarios/)."""
    if not os.path.exists(path):
        candidate = os.path.join(SCENARIO_DIR, path if path.endswith(".json") else path + ".json")
        if os.path.exists(candidate):
            path = candidate
    sc = parse_scenario(read_json(path, "scenario", ScenarioError), path)
    if not os.path.isabs(sc["gains"]):
        sc["gains"] = os.path.join(REPO_ROOT, sc["gains"])
    return sc


def disturbance_at(sc, t_s):
    """The disturbance vector w (volts, 5) in force at time t_s."""
    w = [0.0] * 5
    for d in sc["disturbances"]:
        if d["t_start_s"] <= t_s < d["t_end_s"]:
            w = [a + b for a, b in zip(w, d["w_v"])]
    return w
