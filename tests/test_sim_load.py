"""A payload on link 3 and a sloped floor (hostsim.world.load) in the nonlinear plant."""
import math

import numpy as np
import pytest

from hostsim.model.equations import RobotModel
from hostsim.sim.scenario import ScenarioError, parse_scenario
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.load import Floor, Load, SlopeForce, equilibrium_lean_rad, payload_params
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
    force = SlopeForce(model, alpha)
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


@pytest.mark.parametrize("alpha_deg", [5.0, -5.0, 12.0])
def test_static_equilibrium_on_a_slope_leans_as_computed(params, alpha_deg):
    """Joints straight and the robot at rest on the incline: the lean of link 1 and the motor
    voltages at which the plant's accelerations all vanish (solved on the plant's own
    derivative) are the analytical lean, the wheels holding the pull along the floor."""
    import scipy.optimize
    model = RobotModel("physical", params)
    alpha = math.radians(alpha_deg)
    plant = Plant(model, np.zeros(10), method="heun")
    plant.load = Load(model, floor=Floor(alpha))

    def accel(v):
        th1, u_r, u_l, u2, u3 = v
        x = [0.0, 0.0, th1, 0.0, 0.0] + [0.0] * 5
        return plant._deriv(x, [u_r, u_l, 0.0, u2, u3], plant.load.force(x))[5:]
    sol = scipy.optimize.fsolve(accel, [alpha, 0.0, 0.0, 0.0, 0.0], xtol=1e-13)
    assert np.max(np.abs(accel(sol))) < 1e-9
    lean = sol[0] - alpha                         # th1 is from the floor's normal
    assert lean == pytest.approx(equilibrium_lean_rad(params, alpha), rel=1e-6)
    assert (lean > 0) == (alpha > 0)              # uphill of the axle
    # the wheels' motors hold R_w m g sin(alpha) together, at stall: torque = Km u / Ra
    m_all = params["m1_kg"] + params["m2_kg"] + params["m3_kg"] + 2 * params["mw_kg"]
    torque = sum(params[w + "_km_nm_a"] / params[w + "_ra_ohm"] * u
                 for w, u in (("right_wheel", sol[1]), ("left_wheel", sol[2])))
    assert torque == pytest.approx(params["rw_m"] * m_all * params["g_m_s2"] * math.sin(alpha), rel=1e-6)


def test_a_payload_on_the_axis_leaves_the_upright_equilibrium_but_moves_the_centre(params):
    # 100 g at the top of link 3 (10 cm): the centre from 5 cm to (205 x 5 + 100 x 10) / 305 cm
    p = payload_params(params, 0.1, 0.1)
    assert p["l3_m"] == pytest.approx((0.205 * 0.05 + 0.1 * 0.1) / 0.305)
    model = RobotModel("physical", p)
    assert np.max(np.abs(model.qdd([0.0] * 5, [0.0] * 5, [0.0] * 5))) < 1e-12


def test_a_kink_turns_the_frame_and_keeps_the_robot_where_it_is(params):
    """At the foot of a ramp the state is re-expressed in the incline's frame: th1 and the
    wheels' rolling distance grow by the floor's turn (R_w times it), the encoders and every
    speed are unchanged, the position along the floor too: no second turn at the same place."""
    model = RobotModel("physical", params)
    alpha = math.radians(5.0)
    load = Load(model, floor=Floor(alpha, 0.3, 1.3))
    assert load.slope.angle_rad == 0.0
    x = [0.2998, 0.3000, 0.02, 0.01, -0.01, 0.15, 0.15, 0.1, 0.0, 0.0]
    assert load.reframe(x) is x                      # the axle 0.1 mm before the ramp: still flat
    x = [0.3001, 0.3001, 0.02, 0.01, -0.01, 0.15, 0.15, 0.1, 0.0, 0.0]
    where = load.position_m(x)
    y = load.reframe(x)
    rw = params["rw_m"]
    assert y[2] == pytest.approx(0.02 + alpha) and y[0] == pytest.approx(0.3001 + rw * alpha)
    assert y[5:] == x[5:] and y[3:5] == x[3:5]
    assert y[0] / rw - y[2] == pytest.approx(x[0] / rw - x[2], abs=1e-12)      # the encoder's view
    assert load.position_m(y) == pytest.approx(where) and load.kinks == 1
    assert load.reframe(y) is y and load.slope.angle_rad == alpha
    # the top: back to the flat
    z = list(y)
    z[0] = z[1] = load.s0_m + 1.3 + 1e-4
    w = load.reframe(z)
    assert w[2] == pytest.approx(y[2] - alpha) and load.slope.angle_rad == 0.0 and load.kinks == 2


@pytest.mark.parametrize("cls", [Plant, DrivetrainPlant])
def test_rolling_onto_a_ramp_turns_the_frame_once_and_the_encoders_do_not_jump(params, cls):
    model = RobotModel("physical", params)
    alpha = math.radians(5.0)
    x0 = np.zeros(10)
    x0[5] = x0[6] = 0.3                               # rolling at 0.3 m/s, the ramp 1 cm ahead
    plant = cls(model, x0, method="heun")
    plant.load = Load(model, floor=Floor(alpha, 0.01, 1.0))
    angles = [plant.motor_angles()]
    th1 = [plant.x[2]]
    for _ in range(20):
        plant.advance([0.0] * 5, 0.005)
        angles.append(plant.motor_angles())
        th1.append(plant.x[2])
    assert plant.load.kinks == 1
    steps = np.abs(np.diff(np.array(angles), axis=0))
    assert steps.max() < 0.3 * 0.005 / params["rw_m"] * 1.5        # no more than the rolling explains
    jump = np.diff(th1)
    assert jump.max() == pytest.approx(alpha, abs=0.01)           # the frame's turn, in one step


def _doc(**extra):
    doc = {"modes": ["firmware"], "duration_s": 1.0}
    doc.update(extra)
    return doc


@pytest.mark.parametrize("extra, field", [
    ({"payload": {"mass_kg": 2.0, "distance_m": 0.1}}, "payload.mass_kg"),
    ({"payload": {"mass_kg": 0.1, "distance_m": 0.3}}, "payload.distance_m"),
    ({"payload": {"mass_kg": 0.1}}, "payload"),
    ({"payload": {"mass_kg": 0.1, "distance_m": 0.1, "t_on_s": 5, "t_off_s": 4}}, "payload.t_off_s"),
    ({"slope": {"angle_deg": 50}}, "slope.angle_deg"),
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


@pytest.mark.parametrize("name", ["payload_100g", "payload_put_on", "slope_up_5deg", "slope_down_5deg", "ramp"])
def test_the_load_scenarios_run_on_the_realistic_brick_and_report_what_the_targets_need(name):
    """Each of make sim's payload and slope scenarios (hostsim.studies.sim_study.LOAD_SCENARIOS),
    shortened: the firmware balances on the realistic brick, and the metrics carry the joints'
    offset, the saturated share and, on a slope, link 1's lean beside the analytical one."""
    import dataclasses
    from hostsim.sim import metrics
    from hostsim.sim.firmware_run import run_firmware
    from hostsim.sim.scenario import floor_angle_rad, load_scenario
    from hostsim.studies.sim_study import LOAD_SCENARIOS
    assert name in LOAD_SCENARIOS
    sc = load_scenario(name)
    assert sc.gains.endswith("gains/physical.json") and sc.brick.timed and sc.duration_s == 30.0
    sc = dataclasses.replace(sc, duration_s=3.0)
    run = run_firmware(sc)
    m = metrics.compute(run, sc, 7.6)
    assert m["upright"] and m["completed"]
    assert len(m["joint_offset_rad"]) == 2 and m["saturated_fraction"] is not None
    alpha = floor_angle_rad(sc)
    assert ("equilibrium_lean_rad" in m) == (alpha != 0.0)
    if alpha:
        assert m["equilibrium_lean_rad"] == pytest.approx(0.0164 * np.sign(alpha), abs=5e-4)
        assert run.x[0, 2] - alpha == pytest.approx(0.017, abs=1e-6)     # released 0.017 rad from the vertical


def test_the_ramp_scenario_drives_over_its_ramp():
    from hostsim.sim.scenario import load_scenario
    sc = load_scenario("ramp")
    travel = sum(v * d for v, _, d in sc.course)
    assert sc.slope.angle_deg == 5.0 and sc.slope.ramp_end_m - sc.slope.ramp_start_m == pytest.approx(1.0)
    assert 0.0 < sc.slope.ramp_start_m and travel > sc.slope.ramp_end_m + 0.2


def test_make_sims_load_table_shows_the_joints_the_hunting_and_the_lean():
    from hostsim.studies.report import load_table
    m = {"upright": True, "completed": True, "stop_reason": "completed", "duration_s": 30.0,
         "joint_offset_rad": [0.0123, 0.0046], "saturated_fraction": 0.002,
         "oscillation_above_1hz": {"th2": {"hz": 2.5, "amplitude": 0.0021}, "th3": {"hz": 2.5, "amplitude": 0.0004}},
         "lean_from_vertical_rad": 0.0161, "equilibrium_lean_rad": 0.0164}
    fell = dict(m, upright=False, completed=False, stop_reason="joint_limit", duration_s=13.1)
    del fell["equilibrium_lean_rad"]
    rows = load_table([{"scenario": "slope_up_5deg", "runs": {"firmware/optimal": m}},
                       {"scenario": "payload_100g", "runs": {"firmware/optimal": fell}}]).splitlines()
    assert rows[2] == ("| slope_up_5deg | firmware/optimal | yes | - | 0.012 | 0.005 | 0.2 | 2.1, 0.4 | "
                       "0.0161 (0.0164) |")
    assert rows[3].startswith("| payload_100g | firmware/optimal | no (joint_limit) | 13.1 |") and rows[3].endswith("| - |")
