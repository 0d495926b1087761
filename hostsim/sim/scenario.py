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
  sensor models (hostsim.sim.firmware_run). Its estimate starts from the first measurement, as on the
  robot (``xhat0`` does not apply), and its wheel-position origin is where the wheels stand
  at start (see hostsim.sim.firmware_run).

``controllers``: ``optimal`` (LQR + detector + K_w) and/or ``pd`` (the Appendix D
baseline of hostsim.model.pd); each mode runs once per controller.

``brick`` (firmware mode only): what makes the simulated EV3 as unkind as the real one, each
effect off by default (``Brick``; realistic values, with their sources, in
scenarios/brick_realistic.json; docs/architecture.md describes the models).
``firmware_config``: fields of the firmware's configuration to override (e.g. the start
pose it is told, which the plant's x0 need not match). What the firmware will be told (x0's
pose unless overridden, then these fields) is checked when the scenario is read, by the
configuration's own bounds (tipbot_fw.config), and named ``firmware_config.<field>``.

``payload`` (nonlinear and firmware modes): a point mass on link 3, ``mass_kg`` (at most 1)
``distance_m`` from its joint (at most 0.1, the link's top), from ``t_on_s`` (default 0) until
``t_off_s`` (default: the end). ``slope``: the floor rising ``angle_deg`` forward (negative:
falling; at most 45), everywhere, or only between ``ramp_start_m`` and ``ramp_end_m`` along the
floor from where the axle starts (both or neither). The plant's angles are then measured from
the floor's normal: a robot released upright on a slope starts at th1 = the slope's angle
(hostsim.world.load; the firmware's start pose is absolute, as its gyro is).
"""
import dataclasses
import math
import os
from typing import Optional

from hostsim.errors import TipbotError
from hostsim.model.params import REQUIRED
from hostsim.paths import REPO_ROOT
from tipbot_fw import config as fw_config
from tipbot_fw import fields
from tipbot_fw.drive.course import CourseError, parse_course
from tipbot_fw.guard.plausibility import BATTERY_MAX_V, BATTERY_MIN_V

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
    "pushes": [],                     # [{"t_s", "th1_dot_rad_s"}]: link 1's rate jumps, or
                                      # [{"t_s", "link", "impulse_n_s"}]: a horizontal impulse
                                      # at that link's centre of mass (forward positive)
    "sensors": {},                    # see SENSOR_DEFAULTS
    "extra_delay_ticks": 0,
    "io_latency_s": 0.002,            # firmware: tick start to its duties taking effect
    "jitter_s": 0.0,                  # std of the loop's wake-up jitter (firmware in the loop)
    "seed": 0,
    "brick": {},                      # the simulated EV3's imperfections (Brick; firmware mode)
    "firmware_config": {},            # overrides of the firmware's configuration
    "modes": ["linear", "firmware"],  # which simulations to run (MODES)
    "settle_band_rad": 0.02,          # |th1| band for the settling time
    "expect": {},                     # optional pass criteria checked by `hostsim run`
    "reference_governor": False,      # linear/nonlinear: the law follows hostsim.sim.governor's reference
    "payload": None,                  # a point mass on link 3 (Payload; nonlinear, firmware)
    "slope": None,                    # the floor's slope (Slope; nonlinear, firmware)
    "course": None,                   # drive segments from the release (firmware; docs/course-format.md)
}


@dataclasses.dataclass(frozen=True)
class Disturbance:
    """Volts added to the inputs [u_r, u_l, -, u_th2, u_th3] from t_start_s to t_end_s."""
    t_start_s: float
    t_end_s: float
    w_v: tuple


@dataclasses.dataclass(frozen=True)
class Push:
    """At t_s, link 1's rate jumps by th1_dot_rad_s; or, with impulse_n_s, a horizontal
    impulse (N s, forward positive) hits link ``link`` (1-3) at its centre of mass."""
    t_s: float
    th1_dot_rad_s: float = 0.0
    link: int = 1
    impulse_n_s: Optional[float] = None


@dataclasses.dataclass(frozen=True)
class Sensors:
    """Sensor imperfections and the battery (hostsim.world.sensors)."""
    gyro_bias_dps: float = 0.0
    gyro_noise_dps: float = 0.0
    gyro_sign: int = 1
    battery_v: float = 8.0


SENSOR_DEFAULTS = dataclasses.asdict(Sensors())


@dataclasses.dataclass(frozen=True)
class Payload:
    """A point mass on link 3 (hostsim.world.load): mass_kg at distance_m along link 3 from
    its joint, put on at t_on_s and taken off at t_off_s (None: stays on)."""
    mass_kg: float
    distance_m: float
    t_on_s: float = 0.0
    t_off_s: Optional[float] = None


@dataclasses.dataclass(frozen=True)
class Slope:
    """The floor rises by angle_deg in the forward direction (negative: falls), between
    ramp_start_m and ramp_end_m along the floor from where the axle starts (flat before and
    after), or everywhere when neither is given (hostsim.world.load)."""
    angle_deg: float
    ramp_start_m: Optional[float] = None
    ramp_end_m: Optional[float] = None


# Bounds: a kilogram on link 3 is most of the robot's own 1.3 kg (the Medium motor holds
# about 0.12 N m stalled: 1 kg at 10 cm is 1 N m); link 3 is 2 l3 = 10 cm long (params);
# 45 degrees: the wheels' motors hold the robot on any slope at stall (0.49 N m at 7.6 V
# against R_w m g sin(alpha), 0.30 N m at 45 degrees), but no tyre does (the plant's wheels
# do not slip: rubber on a floor grips up to tan(alpha) = mu, about 0.6-1, 30-45 degrees).
MAX_PAYLOAD_KG = 1.0
MAX_PAYLOAD_DISTANCE_M = 0.1
MAX_SLOPE_DEG = 45.0
MAX_RAMP_POSITION_M = 10.0


@dataclasses.dataclass(frozen=True)
class Brick:
    """The simulated EV3's imperfections (firmware in the loop), all off by default.
    Times in s, per-motor lists in the order right wheel, left wheel, joint 2, joint 3."""
    # time (hostsim.world.brick_timing): each sysfs access, the tick's Python, the scheduler
    tacho_access_s: tuple = (0.0, 0.0)     # a position read or duty write: uniform in [lo, hi]
    sensor_access_s: tuple = (0.0, 0.0)    # a gyro bin_data or battery read
    compute_s: tuple = (0.0, 0.0)          # the tick's own Python, between reads and writes
    cpu_steal: float = 0.0                 # share of the CPU interrupts take: stretches all of it
    late_wake_probability: float = 0.0     # a wake-up is late (a kernel thread holds the CPU) ...
    late_wake_s: tuple = (0.0, 0.0)        # ... by U(lo, hi)
    stall_rate_hz: float = 0.0             # multi-tick stalls (SD card, kernel threads) per second ...
    stall_s: tuple = (0.0, 0.0)            # ... lasting U(lo, hi)
    single_stall_s: float = 0.0            # one stall this long (0: none) ...
    single_stall_at_s: float = 10.0        # ... at the first wake-up this long after the simulation starts (the
                                           # calibration before the release takes ~1.1 s), plus U(0, 10 ms)
    # encoders (hostsim.world.sensors.EncoderModel)
    encoder_update_s: float = 0.0          # position updated this often (0: at the read)
    encoder_truncate: bool = False         # whole edges passed instead of the nearest count
    # motors (hostsim.world.drivetrain)
    friction_deadband_pct: tuple = (0.0, 0.0, 0.0, 0.0)   # Coulomb friction: the duty at 8 V that starts a free motor
    backlash_deg: tuple = (0.0, 0.0, 0.0, 0.0)            # free play at the output
    # gyro (hostsim.world.gyro)
    gyro_latency_s: float = 0.0
    gyro_freeze_s: float = 0.0             # a UART overrun freezes the reading this long ...
    gyro_freeze_interval_s: float = 0.0    # ... at exponential intervals of this mean (0: never)
    gyro_scale_error: tuple = (0.0, 0.0)   # for positive, negative rates (sensor frame)
    gyro_bias_walk_dps_rt_s: float = 0.0   # bias random walk, deg/s per sqrt(s)
    gyro_bias_ramp_dps_s: float = 0.0      # bias drift, deg/s per s
    gyro_rate_step_dps: float = 0.0        # the rate moves in steps of this (0: 1 deg/s)
    gyro_mode_write_s: float = 0.0         # a mode write blocks this long (hostsim.world.fake_ev3)
    gyro_mode_timeout: bool = False        # an old sensor: mode writes time out (ETIMEDOUT)
    # battery (hostsim.world.sensors.BatteryModel)
    battery_r_ohm: float = 0.0             # internal resistance: sags under the motors' current
    battery_quantum_v: float = 0.0         # voltage_now resolution
    sources: dict = dataclasses.field(default_factory=dict, compare=False)   # field -> where its value comes from

    @property
    def timed(self):
        """Accesses and the scheduler cost time (hostsim.world.brick_timing)."""
        return (self.tacho_access_s[1] > 0 or self.sensor_access_s[1] > 0 or self.compute_s[1] > 0
                or (self.late_wake_probability > 0 and self.late_wake_s[1] > 0)
                or (self.stall_rate_hz > 0 and self.stall_s[1] > 0) or self.single_stall_s > 0)

    @property
    def needs_sysfs(self):
        """Effects that act through the fake EV3 tree: the timing, the gyro's mode write."""
        return self.timed or self.gyro_mode_write_s > 0 or self.gyro_mode_timeout

    @property
    def drivetrain(self):
        return any(self.friction_deadband_pct) or any(self.backlash_deg)

    @property
    def gyro_effects(self):
        return bool(self.gyro_latency_s or (self.gyro_freeze_s and self.gyro_freeze_interval_s)
                    or any(self.gyro_scale_error) or self.gyro_bias_walk_dps_rt_s or self.gyro_bias_ramp_dps_s
                    or self.gyro_rate_step_dps)

    @property
    def ideal(self):
        """Every effect off: today's world (hostsim.world.lockstep.World)."""
        return self == Brick()     # sources do not compare


BRICK_FIELDS = tuple(f.name for f in dataclasses.fields(Brick))
# Physical bounds of the brick's fields: (field, kind, bound). Kinds: "range" a [lo, hi] pair
# with 0 <= lo <= hi <= bound; "motors" four values in [0, bound]; "pair" two values in
# [-bound, bound]; "value" one in [0, bound]; "signed" one in [-bound, bound]; "flag" true or
# false. Far beyond the realistic values (scenarios/brick_realistic.json, ../shared/ev3-hardware.md)
# and the margin sweep's ranges (hostsim.studies.margins), short of what is no EV3 or no test.
BRICK_BOUNDS = (
    ("tacho_access_s", "range", 0.005),          # one access a whole 5 ms tick: a stall, not an access
    ("sensor_access_s", "range", 0.005),
    ("compute_s", "range", 0.05),                # the longest period a gains file may have
    ("cpu_steal", "value", 0.9),
    ("late_wake_probability", "value", 1),
    ("late_wake_s", "range", 0.05),
    ("stall_rate_hz", "value", 10),
    ("stall_s", "range", 1),                     # a second without control is a fall anyway
    ("single_stall_s", "value", 1),
    ("single_stall_at_s", "value", 3600),
    ("encoder_update_s", "value", 0.05),
    ("encoder_truncate", "flag", None),
    ("friction_deadband_pct", "motors", 100),    # the duty at 8 V that starts a free motor
    ("backlash_deg", "motors", 90),
    ("gyro_latency_s", "value", 0.5),
    ("gyro_freeze_s", "value", 1),
    ("gyro_freeze_interval_s", "value", 3600),
    ("gyro_scale_error", "pair", 0.5),
    ("gyro_bias_walk_dps_rt_s", "value", 10),
    ("gyro_bias_ramp_dps_s", "signed", 1),       # 600 deg/s in the longest run: beyond the range
    ("gyro_rate_step_dps", "value", 50),
    ("gyro_mode_write_s", "value", 0.5),         # ten of the driver's 50 ms tries
    ("gyro_mode_timeout", "flag", None),
    ("battery_r_ohm", "value", 5),               # at 5 ohm one amp of the motors sags 5 V: no battery
    ("battery_quantum_v", "value", 1),
)


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
    brick: Brick
    firmware_config: dict
    extra_delay_ticks: int
    io_latency_s: float
    jitter_s: float
    seed: int
    modes: tuple
    settle_band_rad: float
    expect: dict
    reference_governor: bool
    payload: Optional[Payload] = None
    slope: Optional[Slope] = None
    course: Optional[tuple] = None        # ((speed_mps, yaw_rate_rad_s, duration_s), ...)
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
# about 50 MB of trace; a push beyond 20 rad/s on link 1, or an impulse beyond 5 N s (the whole
# 1.3 kg robot at 4 m/s), or 12 V of disturbance is no robot's).
MAX_DURATION_S = 600.0
MAX_TIME_S = 3600.0
MAX_PUSH_RAD_S = 20.0
MAX_IMPULSE_N_S = 5.0
MAX_DISTURBANCE_V = 12.0
STATE_BOUNDS = (10.0, 10.0, 3.2, 3.2, 3.2, 5.0, 5.0, 50.0, 50.0, 50.0)   # m, rad, m/s, rad/s
NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-")


def _vector(f, field, value, length, bounds=None, lo=None, hi=None):
    """value checked as a list of length numbers, each within +-bounds[i] or [lo, hi]."""
    if not isinstance(value, list) or len(value) != length:
        f.fail(field, "must be a list of %d numbers, got %r" % (length, value))
    if bounds is None:
        bounds = [None] * length
    return [f.number("%s[%d]" % (field, i), v, lo=lo if b is None else -b, hi=hi if b is None else b,
                     lo_open=False) for i, (v, b) in enumerate(zip(value, bounds))]


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
    pushes = []
    for i, p in enumerate(sc["pushes"]):
        name = "pushes[%d]" % i
        if isinstance(p, dict) and "impulse_n_s" in p:
            _exactly(f, name, p, ("t_s", "link", "impulse_n_s"))
            f.check(name + ".link", p["link"], fields.one_of(1, 2, 3))
            push = Push(f.number(name + ".t_s", p["t_s"], lo=0, hi=MAX_TIME_S, lo_open=False), link=p["link"],
                        impulse_n_s=f.number(name + ".impulse_n_s", p["impulse_n_s"], lo=-MAX_IMPULSE_N_S,
                                             hi=MAX_IMPULSE_N_S, lo_open=False))
        else:
            _exactly(f, name, p, ("t_s", "th1_dot_rad_s"))
            push = Push(f.number(name + ".t_s", p["t_s"], lo=0, hi=MAX_TIME_S, lo_open=False),
                        f.number(name + ".th1_dot_rad_s", p["th1_dot_rad_s"], lo=-MAX_PUSH_RAD_S,
                                 hi=MAX_PUSH_RAD_S, lo_open=False))
        pushes.append(push)
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
    sc["brick"] = _brick(f, sc["brick"])
    f.check("firmware_config", sc["firmware_config"], fields.obj)
    if "firmware" in sc["modes"] or sc["firmware_config"]:
        # what the firmware will be told, checked now by its own bounds (tipbot_fw.config)
        fw_config.config_from_overrides(firmware_overrides(sc["x0_si"], sensors["gyro_sign"], sc["firmware_config"]),
                                        src, ScenarioError, "firmware_config.")
    if sc["brick"].timed:
        for k, off in (("jitter_s", 0.0), ("extra_delay_ticks", 0)):
            if sc[k] != off:
                f.fail(k, "must be %r with the brick's timing (brick.*_access_s, compute_s, late wakes, stalls "
                          "replace it)" % off)
        if "io_latency_s" in doc:
            f.fail("io_latency_s", "does not apply with the brick's timing (each duty lands at its own write)")
    f.check("extra_delay_ticks", sc["extra_delay_ticks"], fields.number(lo=0, hi=100, lo_open=False, integer=True))
    sc["jitter_s"] = f.number("jitter_s", sc["jitter_s"], lo=0, hi=0.05, lo_open=False)
    sc["io_latency_s"] = f.number("io_latency_s", sc["io_latency_s"], lo=0, hi=0.05, lo_open=False)
    sc["settle_band_rad"] = f.number("settle_band_rad", sc["settle_band_rad"], lo=0, hi=3.2)
    f.check("seed", sc["seed"], fields.number(lo=0, hi=2 ** 32 - 1, lo_open=False, integer=True))
    f.check("expect", sc["expect"], fields.obj)
    f.check("reference_governor", sc["reference_governor"], fields.boolean)
    sc["payload"] = _payload(f, sc["payload"], sc["modes"])
    sc["slope"] = _slope(f, sc["slope"], sc["modes"])
    sc["course"] = _course(f, sc["course"], sc["modes"], src)
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
              pushes=tuple(pushes), firmware_config=dict(sc["firmware_config"]),
              sensors=Sensors(**sensors), param_scale=dict(sc["param_scale"]), expect=dict(sc["expect"]))
    return Scenario(**sc)


def _brick(f, doc):
    """The ``brick`` object -> Brick, every field checked against BRICK_BOUNDS."""
    f.check("brick", doc, fields.obj)
    f.known(doc, BRICK_FIELDS, "brick.")
    out = {}
    if "sources" in doc:
        f.check("brick.sources", doc["sources"], fields.obj)
        for field, text in doc["sources"].items():
            if field not in BRICK_FIELDS:
                f.fail("brick.sources." + field, "names no brick field")
            f.check("brick.sources." + field, text, fields.nonempty_string)
        out["sources"] = dict(doc["sources"])
    for k, kind, bound in BRICK_BOUNDS:
        if k not in doc:
            continue
        name, v = "brick." + k, doc[k]
        if kind == "flag":
            out[k] = f.check(name, v, fields.boolean)
        elif kind in ("value", "signed"):
            out[k] = f.number(name, v, lo=0 if kind == "value" else -bound, hi=bound, lo_open=False)
        else:
            n, lo = (4, 0) if kind == "motors" else (2, -bound if kind == "pair" else 0)
            out[k] = tuple(_vector(f, name, v, n, lo=lo, hi=bound))
            if kind == "range" and out[k][0] > out[k][1]:
                f.fail(name, "must be [lo, hi] with 0 <= lo <= hi, got %r" % (v,))
    return Brick(**out)


def _optional(f, name, doc, keys, required):
    if not isinstance(doc, dict) or not set(required) <= set(doc) or not set(doc) <= set(keys):
        f.fail(name, "must be an object with %s (optional: %s), got %r"
               % (", ".join(required), ", ".join(k for k in keys if k not in required) or "none", doc))


def _payload(f, doc, modes):
    """The ``payload`` object -> Payload or None."""
    if doc is None:
        return None
    _optional(f, "payload", doc, ("mass_kg", "distance_m", "t_on_s", "t_off_s"), ("mass_kg", "distance_m"))
    if "linear" in modes:
        f.fail("payload", "does not apply in linear mode (the linear plant is the gains' model)")
    mass = f.number("payload.mass_kg", doc["mass_kg"], lo=0, hi=MAX_PAYLOAD_KG, lo_open=False)
    dist = f.number("payload.distance_m", doc["distance_m"], lo=0, hi=MAX_PAYLOAD_DISTANCE_M, lo_open=False)
    t_on = f.number("payload.t_on_s", doc.get("t_on_s", 0.0), lo=0, hi=MAX_TIME_S, lo_open=False)
    t_off = doc.get("t_off_s")
    if t_off is not None:
        t_off = f.number("payload.t_off_s", t_off, lo=0, hi=MAX_TIME_S, lo_open=False)
        if t_off <= t_on:
            f.fail("payload.t_off_s", "must be after t_on_s (%r), got %r" % (t_on, t_off))
    return Payload(float(mass), float(dist), float(t_on), None if t_off is None else float(t_off))


def _slope(f, doc, modes):
    """The ``slope`` object -> Slope or None."""
    if doc is None:
        return None
    _optional(f, "slope", doc, ("angle_deg", "ramp_start_m", "ramp_end_m"), ("angle_deg",))
    if "linear" in modes:
        f.fail("slope", "does not apply in linear mode (the linear plant is the gains' model)")
    angle = f.number("slope.angle_deg", doc["angle_deg"], lo=-MAX_SLOPE_DEG, hi=MAX_SLOPE_DEG, lo_open=False)
    if ("ramp_start_m" in doc) != ("ramp_end_m" in doc):
        f.fail("slope", "gives ramp_start_m and ramp_end_m together or neither, got %r" % (doc,))
    if "ramp_start_m" not in doc:
        return Slope(float(angle))
    lo = f.number("slope.ramp_start_m", doc["ramp_start_m"], lo=-MAX_RAMP_POSITION_M, hi=MAX_RAMP_POSITION_M,
                  lo_open=False)
    hi = f.number("slope.ramp_end_m", doc["ramp_end_m"], lo=-MAX_RAMP_POSITION_M, hi=MAX_RAMP_POSITION_M,
                  lo_open=False)
    if hi <= lo:
        f.fail("slope.ramp_end_m", "must be beyond ramp_start_m (%r), got %r" % (lo, hi))
    return Slope(float(angle), float(lo), float(hi))


# A course's bounds here are any robot's (tipbot_fw.gains.REFERENCE_LIMITS); the gains' own
# limits are checked when the firmware loads it (hostsim.sim.firmware_run), as the robot does.
_ANY_ROBOT = {"speed_mps": 2.0, "yaw_rate_dps": 1000.0}


def _course(f, doc, modes, src):
    """The ``course`` list -> tuple of (speed_mps, yaw_rate_rad_s, duration_s) or None."""
    if doc is None:
        return None
    if set(modes) != {"firmware"}:
        f.fail("course", "drives the firmware only: modes must be [\"firmware\"], got %r" % (list(modes),))
    try:
        return tuple(parse_course(doc, src, _ANY_ROBOT, "course"))
    except CourseError as e:
        raise ScenarioError(str(e))


def firmware_overrides(x0_si, gyro_sign, firmware_config, wheel_radius_m=None):
    """The fields a scenario sets in the firmware's configuration (tipbot_fw.config): the start
    pose it is held in (x0's th1..th3), its gyro's sign, the wheel radius (when given), no
    real-time priority; then the scenario's firmware_config, field by field."""
    doc = {"start_pose_rad": {"th1": x0_si[2], "th2": x0_si[3], "th3": x0_si[4]},
           "gyro_sign": int(gyro_sign), "realtime_priority": 0}
    if wheel_radius_m is not None:
        doc["wheel_radius_m"] = wheel_radius_m
    return merged_fields(doc, firmware_config)


def merged_fields(base, extra):
    """base with extra's fields in, nested objects merged field by field."""
    out = dict(base)
    for k, v in extra.items():
        out[k] = merged_fields(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


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


def floor_angle_rad(sc):
    """The floor's angle under a scenario's robot where it is the same everywhere (a constant
    slope; 0 on the flat and on a ramp's profile): link 1's th1 is measured from the floor's
    normal, its lean from the vertical is th1 less this (hostsim.world.load)."""
    return math.radians(sc.slope.angle_deg) if sc.slope is not None and sc.slope.ramp_start_m is None else 0.0


def scenario_load(sc, model, x0_model):
    """The plant's hostsim.world.load.Load for the scenario's payload and slope (None when it
    has neither: the plant then runs exactly as before). x0_model: the plant's start state,
    whose axle position is the floor's origin."""
    if sc.payload is None and sc.slope is None:
        return None
    from hostsim.world.load import Floor, Load
    pl = sc.payload
    payload = None if pl is None else (pl.mass_kg, pl.distance_m, pl.t_on_s, pl.t_off_s)
    floor = None
    if sc.slope is not None:
        floor = Floor(math.radians(sc.slope.angle_deg), sc.slope.ramp_start_m, sc.slope.ramp_end_m)
    s0_m = 0.5 * model.variant.d_scale_m * (float(x0_model[0]) + float(x0_model[1]))
    return Load(model, payload, floor, s0_m)
