"""Simulation scenarios as data files (JSON), validated field by field.

A scenario says what to simulate, not how: initial state and estimate (SI: m, rad, m/s,
rad/s, in ``x0_si``/``xhat0_si``; or as the paper prints them, d and d' in cm and cm/s, in
``x0_paper_units``/``xhat0_paper_units``), the input disturbance schedule (volts on
[u_r, u_l, -, u_th2, u_th3]), duration, which gains file and controllers, the plant variant
and parameter perturbations, sensor imperfections, extra delay, loop jitter. Unknown or
malformed fields are errors naming the field.

Each scenario runs in one or more ``modes`` (hostsim.studies.runner):

- ``linear``: the paper's simulation, the discrete linear model with the detector and the
  control law, ideal full-state measurement (y = x), saturation at u_max_v. The plant is
  the gains file's (A, B), or the linearization of ``plant_variant`` with ``param_scale``
  when they differ from the gains' model. Sensor fields and jitter do not apply.
- ``nonlinear``: the same host-side detector and law on the nonlinear plant (1 kHz, the
  input held over each tick), still with y = x: what the model's nonlinearity and the
  saturation do, without the firmware's signal chain.
- ``firmware``: the unmodified firmware (tipbot_fw) against the nonlinear plant and the
  sensor models (hostsim.sim.fil). Its estimate starts from the first measurement, as on the
  robot (``xhat0`` does not apply), and its wheel-position origin is where the wheels stand
  at start (see hostsim.sim.fil).

``controllers``: ``optimal`` (LQR + detector + K_w) and/or ``pd`` (the Appendix D
baseline of hostsim.model.pd); each mode runs once per controller.
"""
import dataclasses
import os
from typing import Optional

from hostsim.errors import TipbotError
from hostsim.model.params import REQUIRED
from hostsim.paths import REPO_ROOT
from tipbot_fw import fields
from tipbot_fw.plausibility import BATTERY_MAX_V, BATTERY_MIN_V

SCENARIO_DIR = os.path.join(REPO_ROOT, "scenarios")


class ScenarioError(TipbotError):
    """A scenario file is malformed; the message names the file and the field."""


DEFAULTS = {
    "description": "",
    "duration_s": 10.0,
    "gains": "gains/physical.json",
    "controllers": ["optimal"],       # "optimal" (LQR + detector + K_w) and/or "pd" (baseline)
    "plant_variant": "physical",
    "plant_method": "heun",           # integrator of the nonlinear plant at 1 kHz (hostsim.world.plant)
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
    "reference_governor": False,      # linear/nonlinear: the law follows hostsim.sim.governor's reference
}


@dataclasses.dataclass(frozen=True)
class Disturbance:
    """Volts added to the inputs [u_r, u_l, -, u_th2, u_th3] from t_start_s to t_end_s."""
    t_start_s: float
    t_end_s: float
    w_v: tuple


@dataclasses.dataclass(frozen=True)
class Push:
    """An impulse on link 1: its rate jumps by th1_dot_rad_s at t_s."""
    t_s: float
    th1_dot_rad_s: float


@dataclasses.dataclass(frozen=True)
class Sensors:
    """Sensor imperfections and the battery (hostsim.world.sensors)."""
    gyro_bias_dps: float = 0.0
    gyro_noise_dps: float = 0.0
    gyro_sign: int = 1
    battery_v: float = 8.0


SENSOR_DEFAULTS = dataclasses.asdict(Sensors())


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A parsed, validated scenario (see the module docstring and DEFAULTS); SI units, the
    gains path absolute once loaded from a file. Vary one with dataclasses.replace."""
    name: str
    description: str
    duration_s: float
    gains: str
    controllers: tuple
    plant_variant: str
    plant_method: str
    param_scale: dict
    x0_si: tuple
    xhat0_si: Optional[tuple]
    disturbances: tuple
    pushes: tuple
    sensors: Sensors
    extra_delay_ticks: int
    io_latency_s: float
    jitter_s: float
    seed: int
    modes: tuple
    settle_band_rad: float
    expect: dict
    reference_governor: bool
# expect: {"<mode>/<controller>": {key: bound}}; every bound is an upper limit except upright.
EXPECT_KEYS = ("max_abs_th1_rad", "max_abs_th2_rad", "max_abs_th3_rad", "settle_time_s", "max_abs_u_v",
               "final_abs_d_m", "final_est_error", "upright")
MODES = ("linear", "nonlinear", "firmware")
CONTROLLERS = ("optimal", "pd")
PLANT_METHODS = ("rk4", "heun")
PAPER_TO_SI = (0.01, 0.01, 1.0, 1.0, 1.0, 0.01, 0.01, 1.0, 1.0, 1.0)


POSITIVE = fields.number(lo=0)
NON_NEGATIVE = fields.number(lo=0, lo_open=False)

# Physical and practical bounds (the simulator stores every tick of a run: 600 s at 1 kHz is
# about 50 MB of trace; a push beyond 20 rad/s on link 1 or 12 V of disturbance is no robot's).
MAX_DURATION_S = 600.0
MAX_TIME_S = 3600.0
MAX_PUSH_RAD_S = 20.0
MAX_DISTURBANCE_V = 12.0
STATE_BOUNDS = (10.0, 10.0, 3.2, 3.2, 3.2, 5.0, 5.0, 50.0, 50.0, 50.0)   # m, rad, m/s, rad/s
NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-")


def _vector(f, field, value, length, bounds=None):
    if not isinstance(value, list) or len(value) != length:
        f.fail(field, "must be a list of %d numbers, got %r" % (length, value))
    if bounds is None:
        return [f.number("%s[%d]" % (field, i), v) for i, v in enumerate(value)]
    return [f.number("%s[%d]" % (field, i), v, lo=-b, hi=b, lo_open=False) for i, (v, b) in enumerate(zip(value, bounds))]


def parse_scenario(doc, src="<scenario>"):
    """Validate a scenario document and fill in defaults -> Scenario."""
    if not isinstance(doc, dict):
        raise ScenarioError("%s: a scenario is a JSON object" % src)
    f = fields.Fields(src, ScenarioError)
    f.known(doc, set(DEFAULTS) | {"name"})
    sc = dict(DEFAULTS)
    sc.update(doc)
    # the file's own name, made a name, unless the document names itself (then it must be one)
    sc["name"] = doc["name"] if "name" in doc else "".join(
        c if c in NAME_CHARS else "_" for c in os.path.splitext(os.path.basename(src))[0]).lstrip(".") or "scenario"
    if (not isinstance(sc["name"], str) or not sc["name"] or not set(sc["name"]) <= NAME_CHARS
            or sc["name"].startswith(".") or len(sc["name"]) > 80):
        f.fail("name", "must be a name (letters, digits, _ . -; not starting with a dot; at most 80), not a "
               "path, got %r" % (sc["name"],))
    f.check("description", sc["description"], fields.string)
    sc["duration_s"] = f.number("duration_s", sc["duration_s"], lo=0, hi=MAX_DURATION_S)
    _choices(f, "controllers", sc["controllers"], CONTROLLERS)
    _choices(f, "modes", sc["modes"], MODES)
    f.check("plant_variant", sc["plant_variant"], fields.one_of("paper", "physical"))
    f.check("plant_method", sc["plant_method"], fields.one_of(*PLANT_METHODS))
    f.check("gains", sc["gains"], fields.nonempty_string)
    f.check("param_scale", sc["param_scale"], fields.obj)
    f.known(sc["param_scale"], REQUIRED, "param_scale.")
    for name, factor in sc["param_scale"].items():
        f.check("param_scale.%s" % name, factor, fields.number(lo=0.01, hi=100.0, lo_open=False))
    sc["x0_si"] = _state(f, sc, "x0") or [0.0] * 10
    sc["xhat0_si"] = _state(f, sc, "xhat0")
    del sc["x0_paper_units"], sc["xhat0_paper_units"]
    f.check("disturbances", sc["disturbances"], fields.array)
    for i, d in enumerate(sc["disturbances"]):
        name = "disturbances[%d]" % i
        _exactly(f, name, d, ("t_start_s", "t_end_s", "w_v"))
        t0 = f.number(name + ".t_start_s", d["t_start_s"], lo=0, hi=MAX_TIME_S, lo_open=False)
        t1 = f.number(name + ".t_end_s", d["t_end_s"], lo=0, hi=MAX_TIME_S, lo_open=False)
        if t1 < t0:
            f.fail(name, "ends before it starts")
        w = _vector(f, name + ".w_v", d["w_v"], 5, [MAX_DISTURBANCE_V] * 5)
        if w[2] != 0.0:
            f.fail(name + ".w_v[2]", "must be 0 (link 1 has no motor)")
    f.check("pushes", sc["pushes"], fields.array)
    for i, p in enumerate(sc["pushes"]):
        name = "pushes[%d]" % i
        _exactly(f, name, p, ("t_s", "th1_dot_rad_s"))
        f.check(name + ".t_s", p["t_s"], fields.number(lo=0, hi=MAX_TIME_S, lo_open=False))
        f.check(name + ".th1_dot_rad_s", p["th1_dot_rad_s"],
                fields.number(lo=-MAX_PUSH_RAD_S, hi=MAX_PUSH_RAD_S, lo_open=False))
    f.check("sensors", sc["sensors"], fields.obj)
    f.known(sc["sensors"], SENSOR_DEFAULTS, "sensors.")
    sensors = dict(SENSOR_DEFAULTS)
    sensors.update(sc["sensors"])
    f.check("sensors.gyro_bias_dps", sensors["gyro_bias_dps"], fields.number(lo=-100, hi=100, lo_open=False))
    f.check("sensors.gyro_noise_dps", sensors["gyro_noise_dps"], fields.number(lo=0, hi=50, lo_open=False))
    f.check("sensors.battery_v", sensors["battery_v"],
            fields.number(lo=BATTERY_MIN_V, hi=BATTERY_MAX_V, lo_open=False))
    f.check("sensors.gyro_sign", sensors["gyro_sign"], fields.one_of(1, -1))
    sc["sensors"] = sensors
    f.check("extra_delay_ticks", sc["extra_delay_ticks"], fields.number(lo=0, hi=100, lo_open=False, integer=True))
    sc["jitter_s"] = f.number("jitter_s", sc["jitter_s"], lo=0, hi=0.05, lo_open=False)
    sc["io_latency_s"] = f.number("io_latency_s", sc["io_latency_s"], lo=0, hi=0.05, lo_open=False)
    sc["settle_band_rad"] = f.number("settle_band_rad", sc["settle_band_rad"], lo=0, hi=3.2)
    f.check("seed", sc["seed"], fields.number(lo=0, hi=2 ** 32 - 1, lo_open=False, integer=True))
    f.check("expect", sc["expect"], fields.obj)
    f.check("reference_governor", sc["reference_governor"], fields.boolean)
    runs = {"%s/%s" % (m, c) for m in sc["modes"] for c in sc["controllers"]}
    for label, bounds in sc["expect"].items():
        name = "expect.%s" % label
        if label not in runs:
            f.fail(name, "names no run of this scenario (runs: %s)" % ", ".join(sorted(runs)))
        f.check(name, bounds, fields.obj)
        f.known(bounds, EXPECT_KEYS, name + ".")
        for k, v in bounds.items():
            f.check("%s.%s" % (name, k), v, fields.boolean if k == "upright" else POSITIVE)
    sc.update(controllers=tuple(sc["controllers"]), modes=tuple(sc["modes"]), x0_si=tuple(sc["x0_si"]),
              xhat0_si=None if sc["xhat0_si"] is None else tuple(sc["xhat0_si"]),
              disturbances=tuple(Disturbance(float(d["t_start_s"]), float(d["t_end_s"]), tuple(float(v) for v in d["w_v"]))
                                 for d in sc["disturbances"]),
              pushes=tuple(Push(float(q["t_s"]), float(q["th1_dot_rad_s"])) for q in sc["pushes"]),
              sensors=Sensors(**sensors), param_scale=dict(sc["param_scale"]), expect=dict(sc["expect"]))
    return Scenario(**sc)


def _exactly(f, name, value, keys):
    if not isinstance(value, dict) or set(value) != set(keys):
        f.fail(name, "must be an object with exactly %s, got %r" % (", ".join(keys), value))


def _choices(f, field, value, allowed):
    if not isinstance(value, list) or not value or any(not isinstance(v, str) or v not in allowed for v in value):
        f.fail(field, "must be a non-empty list of %s, got %r" % (", ".join(allowed), value))
    if len(set(value)) != len(value):
        f.fail(field, "lists an entry twice: %r" % (value,))


def _state(f, sc, base):
    """x0 / xhat0 from either its SI field or its paper-units field (not both), in SI."""
    si, paper = sc[base + "_si"], sc[base + "_paper_units"]
    if si is not None and paper is not None:
        f.fail(base + "_paper_units", "conflicts with %s_si: give one" % base)
    if si is not None:
        return _vector(f, base + "_si", si, 10, STATE_BOUNDS)
    if paper is not None:
        return [v * k for v, k in zip(_vector(f, base + "_paper_units", paper, 10,
                                              [b / k for b, k in zip(STATE_BOUNDS, PAPER_TO_SI)]), PAPER_TO_SI)]
    return None


def load_scenario(path):
    """Read a scenario file (a path, or a name under scenarios/)."""
    if not os.path.exists(path):
        candidate = os.path.join(SCENARIO_DIR, path if path.endswith(".json") else path + ".json")
        if os.path.exists(candidate):
            path = candidate
    sc = parse_scenario(fields.read_json(path, ScenarioError)[0], path)
    if not os.path.isabs(sc.gains):
        sc = dataclasses.replace(sc, gains=os.path.join(REPO_ROOT, sc.gains))
    if not os.path.isfile(sc.gains):
        raise ScenarioError(fields.message(path, "gains", "names %s, which is no file" % sc.gains))
    return sc


def disturbance_at(sc, t_s):
    """The disturbance vector w (volts, 5) in force at time t_s."""
    w = [0.0] * 5
    for d in sc.disturbances:
        if d.t_start_s <= t_s < d.t_end_s:
            w = [a + b for a, b in zip(w, d.w_v)]
    return w
