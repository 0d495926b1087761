"""A payload on link 3 and a sloped floor (hostsim.world.load) in the nonlinear plant."""
import math

import numpy as np
import pytest

from hostsim.model.equations import RobotModel
from hostsim.sim.scenario import ScenarioError, parse_scenario
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.load import Floor, Load, SlopeForce, payload_params
from hostsim.world.plant import Plant


def test_payload_moves_link_3s_centre_and_adds_its_parallel_axis_inertia(params):
    p = payload_params(params, 0.1, 0.1)
    m3, l3, j3 = params["m3_kg"], params["l3_m"], params["j3_kg_m2"]
    assert p["m3_kg"] == pytest.approx(m3 + 0.1)
    assert p["m3_kg"] * p["l3_m"] == pytest.approx(m3 * l3 + 0.1 * 0.1)
    # inertia about the joint is that of the link plus the point mass's
    assert p["j3_kg_m2"] + p["m3_kg"] * p["l3_m"] ** 2 == pytest.approx(j3 + m3 * l3 ** 2 + 0.1 * 0.1 ** 2)
    assert payload_params(params, 0.0, 0.1) == params


def _potential(p, q, alpha):
    """Gravity's potential in the floor frame, less the flat floor's (the model's own)."""
    th1, th12 = q[2], q[2] + q[3]
    th123 = th12 + q[4]
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    xs = [l1 * math.sin(th1), 2 * l1 * math.sin(th1) + l2 * math.sin(th12),
          2 * l1 * math.sin(th1) + 2 * l2 * math.sin(th12) + l3 * math.sin(th123)]
    ys = [l1 * math.cos(th1), 2 * l1 * math.cos(th1) + l2 * math.cos(th12),
          2 * l1 * math.cos(th1) + 2 * l2 * math.cos(th12) + l3 * math.cos(th123)]
    axle = 0.5 * (q[0] + q[1])
    ms = [p["m1_kg"], p["m2_kg"], p["m3_kg"]]
    v = sum(m * (axle + x) * math.sin(alpha) + m * y * (math.cos(alpha) - 1) for m, x, y in zip(ms, xs, ys))
    return p["g_m_s2"] * (v + 2 * p["mw_kg"] * axle * math.sin(alpha))


def test_slope_force_is_minus_the_gradient_of_gravitys_turned_potential(params):
    model = RobotModel("physical", params)
    alpha = math.radians(7.0)
    force = SlopeForce(model, Floor(alpha))
    rng = np.random.default_rng(3)
    q = list(rng.uniform(-0.5, 0.5, 5))
    got = force.at(q + [0.0] * 5)
    for i in range(5):
        dq = list(q)
        dq[i] += 1e-6
        mq = list(q)
        mq[i] -= 1e-6
        grad = (_potential(params, dq, alpha) - _potential(params, mq, alpha)) / 2e-6
        assert got[i] == pytest.approx(-grad, rel=1e-5, abs=1e-9)


def test_ramp_profile_is_flat_outside_the_ramp(params):
    floor = Floor(0.1, -0.1, 0.9)
    assert [floor.angle_at(s) for s in (-0.2, -0.1, 0.5, 0.9)] == [0.0, 0.1, 0.1, 0.0]


@pytest.mark.parametrize("cls", [Plant, DrivetrainPlant])
def test_robot_at_rest_on_a_slope_rolls_downhill(params, cls):
    """Held upright (absolute vertical: th1 = alpha from the floor's normal), no input: the
    pull along the floor starts it rolling back down; on the flat it stays."""
    model = RobotModel("physical", params)
    alpha = math.radians(5.0)
    out = []
    for a in (alpha, -alpha, 0.0):
        x0 = np.zeros(10)
        x0[2] = a
        plant = cls(model, x0, method="heun")
        plant.load = Load(model, floor=Floor(a))
        plant.advance([0.0] * 5, 0.02)
        out.append(plant.x[5] + plant.x[6])
    assert out[0] < -1e-4 and out[1] > 1e-4
    assert abs(out[2]) < 1e-9


def test_payload_steps_at_its_times_without_an_impulse(params):
    model = RobotModel("physical", params)
    plant = Plant(model, np.zeros(10), method="heun")
    plant.load = Load(model, payload=(0.1, 0.1, 0.01, 0.02))
    plant.advance([0.0] * 5, 0.005)
    assert plant.model.params["m3_kg"] == params["m3_kg"]
    plant.advance([0.0] * 5, 0.01)
    assert plant.model.params["m3_kg"] == pytest.approx(params["m3_kg"] + 0.1)
    assert np.all(plant.x == 0.0)       # upright and at rest: the load adds no motion by itself
    plant.advance([0.0] * 5, 0.01)
    assert plant.model.params == params


def _doc(**extra):
    doc = {"modes": ["firmware"], "duration_s": 1.0}
    doc.update(extra)
    return doc


@pytest.mark.parametrize("extra, field", [
    ({"payload": {"mass_kg": 2.0, "distance_m": 0.1}}, "payload.mass_kg"),
    ({"payload": {"mass_kg": 0.1, "distance_m": 0.3}}, "payload.distance_m"),
    ({"payload": {"mass_kg": 0.1}}, "payload"),
    ({"payload": {"mass_kg": 0.1, "distance_m": 0.1, "t_on_s": 5, "t_off_s": 4}}, "payload.t_off_s"),
    ({"slope": {"angle_deg": 45}}, "slope.angle_deg"),
    ({"slope": {"angle_deg": 5, "ramp_start_m": 0}}, "slope"),
    ({"slope": {"angle_deg": 5, "ramp_start_m": 1, "ramp_end_m": 0}}, "slope.ramp_end_m"),
    ({"slope": {"angle_deg": 5}, "modes": ["linear"]}, "slope"),
])
def test_bad_payload_and_slope_fields_are_named(extra, field):
    with pytest.raises(ScenarioError) as e:
        parse_scenario(_doc(**extra), "x.json")
    msg = str(e.value)
    assert "\n" not in msg and field in msg


def test_good_payload_and_slope_parse():
    sc = parse_scenario(_doc(payload={"mass_kg": 0.1, "distance_m": 0.1, "t_on_s": 10, "t_off_s": 20},
                             slope={"angle_deg": -5, "ramp_start_m": -0.1, "ramp_end_m": 0.9}), "x.json")
    assert (sc.payload.mass_kg, sc.payload.t_off_s) == (0.1, 20.0)
    assert (sc.slope.angle_deg, sc.slope.ramp_end_m) == (-5.0, 0.9)
    assert parse_scenario(_doc(), "x.json").payload is None
