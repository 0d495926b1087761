"""The gains file's ``preflight`` block: what the owner's experiments should measure on the robot
these gains were made for, and how far off the measurement may be before they no longer hold it.

The pre-flight check (tipbot_fw.preflight, ``python3 -m tipbot_fw check --gains FILE
--fall-log LOG [--swing-log LOG]...``) fits the robot's fall test and swing tests
(tipbot_fw.bodyfit) and compares them with this block:

- ``fall_pole_1_s``: the fall test's pole of the design's parameters (hostsim.model.bodies);
- ``levers_kg_m``: the joints' levers a1 (the axle), a2, a3;
- each with its **robust interval**: the range of that quantity over which the design's loop
  (its Kalman filter and law on the physical model) keeps the margins the design was made with
  (every mode decaying, every oscillation above 0.5 Hz damped: hostsim.model.kalman.Margins)
  over the design's spread of I/O delay (0-4 ms) and motor gain (+-20 %): loop_holds. The robot is moved along one family per quantity,
  the other parameters as designed: the joint levers by link 2's or link 3's mass (and its
  inertia with it: a heavier part of the same shape), the fall pole by the links' lengths (the
  inertias with their square: the same robot taller or shorter). The bounds are found by
  bisection on the factor (within FACTOR_RANGE, to BISECTION_STEPS halvings of its logarithm:
  0.3 % of the factor) and rounded to three digits, so that a regeneration on another CPU lands on
  the same numbers;
- ``wheel_term_kg_m2`` and ``lever_axle_kg_m`` for the fall's fit (its e = A / Mh), and the
  design's motor constants are in the file's ``parameters``.

A measured value outside its interval, or inside by less than its standard deviation, means the
gains were not made for this robot, or may hold it only by luck: the check refuses and says which
measurement and by how much (tipbot_fw.preflight).
"""
import math

from hostsim.model import bodies, kalman
from hostsim.model.params import scaled_params

FACTOR_RANGE = (0.2, 5.0)
BISECTION_STEPS = 9
FAMILIES = (
    ("fall_pole_1_s", "the links' lengths (inertias with their square)",
     lambda f: {"l1_m": f, "l2_m": f, "l3_m": f, "j1_kg_m2": f * f, "j2_kg_m2": f * f, "j3_kg_m2": f * f},
     bodies.fall_pole),
    ("lever2_kg_m", "link 2's mass (and its inertia)", lambda f: {"m2_kg": f, "j2_kg_m2": f},
     lambda p: bodies.levers(p)[1]),
    ("lever3_kg_m", "link 3's mass (and its inertia)", lambda f: {"m3_kg": f, "j3_kg_m2": f},
     lambda p: bodies.levers(p)[2]),
)


def loop_holds(kd, params, ts_s):
    """The design's loop on the physical plant of ``params`` keeps the margins the design was made
    with (hostsim.model.kalman.Margins.robust: every mode decaying, every oscillation damped) over
    the same spread of I/O delay and motor gain (kalman.ROBUST_DELAYS_S, ROBUST_INPUT_GAINS).

    Not mere stability at one delay: a robot the loop holds only when the brick's timing and the
    battery are kind is not one the gains were made for (a link 3 twice as heavy as described is
    stable at 2 ms and a nominal motor, unstable at 4 ms or a motor 20 % stronger)."""
    plants = kalman.model_plants("physical", params, 1.0, ts_s, kalman.ROBUST_DELAYS_S[::-1],
                                 kalman.ROBUST_INPUT_GAINS[::-1])      # the harder first
    return kalman.UncertaintySet.of(plants).holds(kd)


def _edge(holds, inside, outside):
    """The factor between inside (holds) and outside (does not), by bisection of the logarithm."""
    a, b = math.log(inside), math.log(outside)
    for _ in range(BISECTION_STEPS):
        m = 0.5 * (a + b)
        if holds(math.exp(m)):
            a = m
        else:
            b = m
    return math.exp(a)


def robust_factors(kd, params, ts_s, scale_of):
    """(lo, hi): the factors of a family within which the loop holds (FACTOR_RANGE's ends if it
    holds there; (1, 1) if it does not hold the design's own parameters)."""
    def holds(f):
        return loop_holds(kd, scaled_params(scale_of(f), params), ts_s)
    if not holds(1.0):
        return 1.0, 1.0
    lo, hi = FACTOR_RANGE
    lo = lo if holds(lo) else _edge(holds, 1.0, lo)
    hi = hi if holds(hi) else _edge(holds, 1.0, hi)
    return lo, hi


def _round3(x):
    return float("%.3g" % x)


def preflight_block(kd, params, ts_s):
    """The gains file's ``preflight`` block (module docstring) of a design's Kalman block ``kd``."""
    out = {"fall_pole_1_s": bodies.fall_pole(params), "levers_kg_m": list(bodies.levers(params)),
           "wheel_term_kg_m2": bodies.wheel_term(params), "lever_axle_kg_m": bodies.levers(params)[0],
           "intervals": {}, "families": {},
           "what": "the fall pole and the joints' levers of these gains' robot (hostsim.model.bodies), each with the "
                   "interval over which this design's loop keeps its robust margins on the physical model "
                   "(0-4 ms delay, motor gain +-20 %), the robot moved along the family named; tipbot_fw.preflight compares the owner's "
                   "fall and swing tests with them"}
    for name, family, scale_of, quantity in FAMILIES:
        lo, hi = robust_factors(kd, params, ts_s, scale_of)
        values = sorted(quantity(scaled_params(scale_of(f), params)) for f in (lo, hi))
        out["intervals"][name] = [_round3(values[0]), _round3(values[1])]
        out["families"][name] = {"moved": family, "factors": [_round3(lo), _round3(hi)]}
    return out


def check_measured(block, name, value, rel_se=0.0):
    """-> None if value (with its relative standard error) lies within the block's interval for
    name, else a one-line reason."""
    lo, hi = block["intervals"][name]
    margin = 2.0 * rel_se * value
    if lo <= value + margin and value - margin <= hi:
        return None
    return "%s measured %.4g, outside %.4g..%.4g" % (name, value, lo, hi)


def describe(block):
    """Lines for the owner's report."""
    lines = []
    model = {"fall_pole_1_s": block["fall_pole_1_s"], "lever2_kg_m": block["levers_kg_m"][1],
             "lever3_kg_m": block["levers_kg_m"][2]}
    for name in ("fall_pole_1_s", "lever2_kg_m", "lever3_kg_m"):
        lo, hi = block["intervals"][name]
        lines.append("  %-14s model %.4g, the gains hold %.4g..%.4g (%+.0f %% .. %+.0f %%; moved: %s)" % (
            name, model[name], lo, hi, 100 * (lo / model[name] - 1), 100 * (hi / model[name] - 1),
            block["families"][name]["moved"]))
    return lines


