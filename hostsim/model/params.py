"""Robot parameters: one JSON file, SI units, every value with its source.

The file (default ``params/robot.json``) maps each parameter name to
``{"value": number, "source": text}``. Names carry their unit. Loading checks every
field and names the first bad one.
"""
import hashlib
import json
import os

from hostsim.errors import ParameterError
from hostsim.paths import REPO_ROOT
from tipbot_fw import fields
from tipbot_fw.vocabulary import MOTOR_ROLES

DEFAULT_PARAMS_PATH = os.path.join(REPO_ROOT, "params", "robot.json")

MOTOR_FIELDS = ("beta_nm_s", "ke_v_s", "km_nm_a", "ra_ohm", "jm_kg_m2")

# Lengths, masses and inertias must be > 0; friction may be 0 (a frictionless motor is a
# valid idealisation), nothing may be negative.
POSITIVE = (
    "l1_m", "l2_m", "l3_m", "m1_kg", "m2_kg", "m3_kg", "mw_kg", "rw_m", "track_m",
    "j1_kg_m2", "j2_kg_m2", "j3_kg_m2", "jw_kg_m2", "g_m_s2", "u_max_v",
) + tuple("%s_%s" % (r, f) for r in MOTOR_ROLES for f in ("ke_v_s", "km_nm_a", "ra_ohm", "jm_kg_m2"))
NON_NEGATIVE = tuple("%s_beta_nm_s" % r for r in MOTOR_ROLES)
REQUIRED = POSITIVE + NON_NEGATIVE

# Physical ranges [lo, hi] (SI) of a LEGO robot of this kind, by the end of the name; a value
# outside is a typo or a unit mistake (cm for m, g for kg), not a robot.
RANGES = (
    ("rw_m", 0.005, 0.1),            # LEGO wheels: 8 mm to 47 mm
    ("track_m", 0.02, 1.0),
    ("_m", 1e-3, 0.5),               # link lengths
    ("mw_kg", 1e-3, 1.0),
    ("_kg", 1e-3, 5.0),
    ("jw_kg_m2", 1e-8, 1e-2),
    ("jm_kg_m2", 1e-8, 1e-2),
    ("_kg_m2", 1e-8, 0.1),
    ("g_m_s2", 9.7, 9.9),            # the Earth's surface
    ("u_max_v", 1.0, 11.0),          # tipbot_fw.guard.plausibility: what an EV3 battery gives
    ("ke_v_s", 1e-3, 2.0),
    ("km_nm_a", 1e-3, 2.0),
    ("ra_ohm", 0.5, 100.0),
    ("beta_nm_s", 0.0, 0.1),
)


def value_range(name):
    for suffix, lo, hi in RANGES:
        if name.endswith(suffix):
            return lo, hi
    raise KeyError(name)


def parse_params(doc, source="<parameters>"):
    """Validate a parameters document (the parsed JSON) and return ``{name: float}``."""
    f = fields.Fields(source, ParameterError)
    if not isinstance(doc, dict):
        raise ParameterError("%s: must be a JSON object" % source)
    f.require(doc, ("parameters",))
    entries = f.check("parameters", doc["parameters"], fields.obj)
    f.known(entries, REQUIRED, "parameters.")
    f.require(entries, REQUIRED, "parameters.")
    values = {}
    for name in REQUIRED:
        entry = entries[name]
        raw = entry.get("value") if isinstance(entry, dict) else entry
        lo, hi = value_range(name)
        values[name] = f.number("parameters.%s" % name, raw, lo=lo, hi=hi, lo_open=False)
    return values


def load_params(path=DEFAULT_PARAMS_PATH):
    """Read and validate a parameters file; errors name the file and the field."""
    return parse_params(fields.read_object(path, ParameterError), source=path)


def scaled_params(scale, params=None):
    """Parameters (default: the parameters file's) with multipliers applied: {name: factor}."""
    p = dict(load_params() if params is None else params)
    for name, factor in scale.items():
        p[name] = p[name] * factor
    return p


def params_hash(values):
    """sha256 of the canonical JSON of the parameter values (what the gains were made from)."""
    canon = json.dumps({k: repr(float(v)) for k, v in sorted(values.items())}, sort_keys=True)
    return hashlib.sha256(canon.encode("ascii")).hexdigest()


def payload_params(params, mass_kg, distance_m):
    """params with link 3 carrying a point mass mass_kg at distance_m from its joint, on its
    axis: link 3 and the mass one rigid body, its mass m3 + m, its centre moved along the link,
    its inertia about the new centre by the parallel-axis theorem (l3 is only link 3's centre
    of mass in the equations: nothing sits above it; hostsim.world.load)."""
    if mass_kg <= 0.0:
        return dict(params)
    m3, l3, j3 = params["m3_kg"], params["l3_m"], params["j3_kg_m2"]
    m = m3 + mass_kg
    c = (m3 * l3 + mass_kg * distance_m) / m
    out = dict(params)
    out["m3_kg"] = m
    out["l3_m"] = c
    out["j3_kg_m2"] = j3 + m3 * (l3 - c) ** 2 + mass_kg * (distance_m - c) ** 2
    return out
