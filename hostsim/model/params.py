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
from tipbot_fw.config import MOTOR_ROLES

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
        values[name] = f.number("parameters.%s" % name, raw, lo=0, lo_open=name in POSITIVE)
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
