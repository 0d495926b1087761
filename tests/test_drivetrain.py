"""The drivetrain (hostsim.world.drivetrain): Coulomb friction with stick-slip, gear backlash as
a free play between rotor and load, and the ideal plant when both are off."""
import math

import numpy as np
import pytest

from hostsim.model.equations import RobotModel
from hostsim.sim.firmware_build import friction_torques_nm
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.plant import Plant, link_push_impulse

BATTERY_V = 8.0
REALISTIC_DEADBAND_PCT = (4, 4, 4, 10)      # scenarios/brick_realistic.json
JOINT3 = 4                                  # index of u_th3 and of th3 in q


@pytest.fixture(scope="module")
def model(params):
    return RobotModel("physical", params)


def run(plant, u, seconds, record=None):
    out = []
    for _ in range(int(round(seconds / plant.dt_s))):
        plant.advance(u, plant.dt_s)
        if record:
            out.append(record(plant))
    return out


def test_without_friction_and_backlash_it_is_the_ideal_plant(model):
    x0 = np.array([0.0, 0.01, 0.05, 0.02, -0.01, 0.0, 0.0, 0.1, 0.0, 0.0])
    a, b = Plant(model, x0, method="heun"), DrivetrainPlant(model, x0, method="heun")
    u = [1.0, 0.5, 0.0, 0.3, 0.2]
    run(a, u, 0.3)
    run(b, u, 0.3)
    assert np.allclose(a.x, b.x, rtol=0, atol=1e-12)
    assert np.allclose(b.motor_angles(), a.motor_angles(), rtol=0, atol=1e-12)


@pytest.mark.parametrize("duty_pct, moves", [(9.0, False), (11.0, True)])
def test_a_duty_below_the_break_away_does_not_move_a_free_motor(model, params, duty_pct, moves):
    """The Medium motor of joint 3 (10 % dead band) on the robot at rest at its upright
    equilibrium: 9 % does not turn it at all, 11 % does."""
    tau = friction_torques_nm(REALISTIC_DEADBAND_PCT, params)
    plant = DrivetrainPlant(model, np.zeros(10), friction_nm=tau)
    u = [0.0] * 5
    u[JOINT3] = duty_pct / 100.0 * BATTERY_V
    th3 = run(plant, u, 0.2, lambda p: p.x[JOINT3])
    if moves:
        assert th3[-1] > 0.01 and not plant.motors[3].stuck
    else:
        assert max(abs(v) for v in th3) < 1e-12 and plant.motors[3].stuck


def test_friction_stops_a_coasting_motor_and_holds_it(model, params):
    tau = friction_torques_nm(REALISTIC_DEADBAND_PCT, params)
    plant = DrivetrainPlant(model, np.zeros(10), friction_nm=tau)
    u = [0.0] * 5
    u[JOINT3] = 0.3 * BATTERY_V
    run(plant, u, 0.01)
    assert plant.x[5 + JOINT3] > 0.3
    th3 = np.array(run(plant, [0.0] * 5, 0.3, lambda p: p.x[JOINT3]))
    moving = np.abs(np.diff(th3)) > 1e-12
    stop = int(np.argmin(moving))
    assert 0 < stop < 100 and not moving[stop:].any()       # stopped within 0.1 s, then not creeping
    assert th3[-1] > 0.001 and plant.motors[3].stuck


def test_backlash_the_wheel_stops_following_the_motor_inside_the_free_play(model):
    gap = math.radians(3.0)
    plant = DrivetrainPlant(model, np.zeros(10), backlash_rad=(gap, 0.0, 0.0, 0.0))
    rec = lambda p: (p.motor_angles()[0], p.load_angles()[0])
    # forward: the rotor crosses half the gap alone, then drives the wheel
    fwd = run(plant, [2.0, 0.0, 0.0, 0.0, 0.0], 0.06, rec)
    # backward: the rotor crosses the whole gap while the wheel rolls on untouched
    back = run(plant, [-2.0, 0.0, 0.0, 0.0, 0.0], 0.08, rec)
    motor = np.array([m for m, _ in fwd + back])
    wheel = np.array([w for _, w in fwd + back])
    play = motor - wheel
    assert np.all(np.abs(play) <= 0.5 * gap + 1e-9)
    inside = np.abs(play) < 0.5 * gap - 1e-9
    first_contact = int(np.argmax(~inside))
    assert first_contact > 0 and motor[first_contact - 1] > math.radians(1.0)
    assert np.all(wheel[:first_contact] == 0.0)                      # the wheel has not moved
    engaged = ~inside[:len(fwd)]
    assert engaged.sum() > 10 and np.allclose(play[:len(fwd)][engaged], 0.5 * gap)
    # after the reversal the rotor leaves the wheel: inside the gap the wheel keeps its speed
    rev = len(fwd) + int(np.argmax(np.diff(motor[len(fwd):]) < 0))
    crossing = [k for k in range(rev, len(motor)) if inside[k]]
    assert len(crossing) > 5
    wheel_speed = np.diff(wheel)[crossing[1]:crossing[-1]]
    assert np.all(wheel_speed > 0) and np.ptp(wheel_speed) < 0.05 * wheel_speed.max()
    assert play[-1] == pytest.approx(-0.5 * gap)                      # and meets it on the other side
    assert plant.impacts >= 2


def test_an_impact_conserves_momentum_along_the_drive(model):
    """The rotor meets its load plastically: the generalized momentum along the motor's
    direction (load plus rotor) is the same just before and after."""
    gap = math.radians(3.0)
    plant = DrivetrainPlant(model, np.zeros(10), backlash_rad=(0.0, 0.0, gap, 0.0))
    joint2 = plant.motors[2]
    before = None
    for _ in range(200):
        q, qd = plant.x[:5].copy(), plant.x[5:].copy()
        m = model.mass_matrix(q)
        m[3, 3] -= joint2.jm                    # the load's own inertia, without the rotor
        p_load = (m @ qd)[3]
        p_rotor = joint2.jm * joint2.omega if joint2.free else joint2.jm * qd[3]
        was_free = joint2.free
        plant.advance([0.0, 0.0, 0.0, 3.0, 0.0], 0.001)
        if was_free and not joint2.free:
            after = (model.mass_matrix(plant.x[:5]) @ plant.x[5:])[3]
            before = p_load + p_rotor
            break
    assert before is not None, "the gap never closed"
    # one integration step of torque lies between the two (the motor's and gravity's)
    assert after == pytest.approx(before, rel=0.05)


def test_paper_variant_has_no_rotors_to_free(params):
    with pytest.raises(ValueError, match="physical model"):
        DrivetrainPlant(RobotModel("paper", params), np.zeros(10), friction_nm=(0.01,) * 4)


def test_a_push_on_link_3_adds_the_energy_of_its_impulse(model):
    plant = Plant(model, np.zeros(10), method="heun")
    impulse = 0.2
    p_gen = link_push_impulse(model, plant.x[:5], 3, impulse)
    plant.apply_impulse(p_gen)
    m = model.mass_matrix(np.zeros(5))
    j = np.array(p_gen) / impulse
    # from rest: E = P^2 J M^-1 J^T / 2, and link 3's centre of mass moves forward
    added = model.energy(np.zeros(5), plant.x[5:]) - model.energy(np.zeros(5), np.zeros(5))
    assert added == pytest.approx(0.5 * impulse ** 2 * j @ np.linalg.solve(m, j))
    assert j @ plant.x[5:] > 0
