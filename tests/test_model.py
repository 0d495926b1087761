"""The symbolic model: structure, energy, linearization, and the paper's conventions."""
import itertools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hostsim.model.equations import RobotModel, get_variant

VARIANTS = ("paper", "physical")


@pytest.fixture(scope="module")
def models(params):
    return {v: RobotModel(v, params) for v in VARIANTS}


@pytest.mark.parametrize("variant", VARIANTS)
def test_mass_matrix_symmetric_positive_definite_over_poses(models, variant):
    grid = np.linspace(-1.2, 1.2, 5)
    for th1, th2, th3 in itertools.product(grid, grid, grid):
        m = models[variant].mass_matrix([0.3, -0.2, th1, th2, th3])
        assert np.allclose(m, m.T, rtol=1e-12, atol=1e-15)
        assert np.linalg.eigvalsh(m).min() > 0


def undamped(params):
    """Parameters with no back-EMF and no friction: nothing dissipates energy."""
    p = dict(params)
    for role in ("right_wheel", "left_wheel", "joint2", "joint3"):
        p[role + "_ke_v_s"] = 0.0
        p[role + "_beta_nm_s"] = 0.0
    return p


@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
def test_unforced_undamped_model_conserves_energy(params, variant):
    model = RobotModel(variant, undamped(params))
    x0 = np.array([0.0, 0.0, 0.4, -0.6, 0.8, 0.5, -0.3, 0.2, 0.1, -0.4])
    e0 = model.energy(x0[:5], x0[5:])
    sol = solve_ivp(lambda t, x: model.xdot(x, np.zeros(5)), (0.0, 5.0), x0,
                    method="DOP853", rtol=1e-12, atol=1e-12, dense_output=False)
    assert sol.success
    energies = [model.energy(x[:5], x[5:]) for x in sol.y.T]
    drift = max(abs(e - e0) for e in energies) / abs(e0)
    assert drift < 1e-6
    # The motion is not trivial: the links swing through a large range.
    assert np.ptp(sol.y[2]) > 0.5


def test_energy_dissipates_with_back_emf(models):
    """With the motors' back-EMF present, energy must decrease (the check above is not vacuous)."""
    model = models["physical"]
    x0 = np.array([0.0, 0.0, 0.2, -0.3, 0.3, 0.5, -0.3, 0.2, 0.1, -0.4])
    sol = solve_ivp(lambda t, x: model.xdot(x, np.zeros(5)), (0.0, 0.5), x0, rtol=1e-10, atol=1e-10)
    mech = [model.energy(x[:5], x[5:]) for x in sol.y.T]
    # Gravity makes the upright unstable, so compare with the energy the fall released.
    assert mech[-1] < mech[0] - 1e-4


@pytest.mark.parametrize("variant", VARIANTS)
def test_linearization_matches_finite_differences(models, variant):
    model = models[variant]
    ac, bc = model.linearize()
    eps = 1e-6
    num_a = np.zeros((10, 10))
    for j in range(10):
        dx = np.zeros(10)
        dx[j] = eps
        num_a[:, j] = (model.xdot(dx, np.zeros(5)) - model.xdot(-dx, np.zeros(5))) / (2 * eps)
    num_b = np.zeros((10, 5))
    for j in (0, 1, 3, 4):
        du = np.zeros(5)
        du[j] = eps
        num_b[:, j] = (model.xdot(np.zeros(10), du) - model.xdot(np.zeros(10), -du)) / (2 * eps)
    assert np.allclose(ac, num_a, rtol=1e-6, atol=1e-7 * np.abs(ac).max())
    assert np.allclose(bc, num_b, rtol=1e-6, atol=1e-7 * np.abs(bc).max())
    assert np.all(bc[:, 2] == 0)


def appendix_b_mass_matrix(p, th1, th2, th3):
    """Appendix B's M(q), typed from the paper, with the README's corrected C1, C2.

    The paper's d is in cm while its mechanics are SI: rows/columns of d scale by 1e-2.
    """
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    m1, m2, m3, mw = p["m1_kg"], p["m2_kg"], p["m3_kg"], p["mw_kg"]
    j1, j2, j3, jw, rw = p["j1_kg_m2"], p["j2_kg_m2"], p["j3_kg_m2"], p["jw_kg_m2"], p["rw_m"]
    m = m1 + m2 + m3
    c1 = m / 2 + mw + 2 * jw / rw ** 2
    c2 = -jw / rw ** 2
    c3 = l1 * m1 / 2 + l1 * m2 + l1 * m3
    c4 = l2 * m2 / 2 + l2 * m3
    c5 = l3 * m3 / 2
    c6 = 2 * l1 * l2 * m2 + 4 * l1 * l2 * m3
    c7 = 4 * l2 * l3 * m3
    c8 = j1 + l1 ** 2 * m1 + 4 * l1 ** 2 * m2 + 4 * l1 ** 2 * m3 + l2 ** 2 * m2 + 4 * l2 ** 2 * m3 + l3 ** 2 * m3
    c9 = l2 ** 2 * m2 + 4 * l2 ** 2 * m3 + l3 ** 2 * m3
    c10 = 4 * l1 * l3 * m3
    c11 = 2 * l1 * l3 * m3
    c12 = m3 * l3 ** 2
    c13 = c7 / 2
    c14 = j2 + l2 ** 2 * m2 + 4 * l2 ** 2 * m3 + l3 ** 2 * m3
    c15 = m3 * l3 ** 2 + j3
    cos = np.cos
    mm = np.zeros((5, 5))
    mm[0, 0] = mm[1, 1] = c1
    mm[0, 1] = mm[1, 0] = c2
    m3_ = c3 * cos(th1) + c4 * cos(th1 + th2) + c5 * cos(th1 + th2 + th3)
    m4_ = c4 * cos(th1 + th2) + c5 * cos(th1 + th2 + th3)
    m5_ = c5 * cos(th1 + th2 + th3)
    for i in (0, 1):
        mm[i, 2] = mm[2, i] = m3_
        mm[i, 3] = mm[3, i] = m4_
        mm[i, 4] = mm[4, i] = m5_
    mm[2, 2] = 2 * c6 * cos(th2) + c7 * cos(th3) + c10 * cos(th2 + th3) + c8
    mm[2, 3] = mm[3, 2] = c6 * cos(th2) + c7 * cos(th3) + c11 * cos(th2 + th3) + c9
    mm[2, 4] = mm[4, 2] = c13 * cos(th3) + c12 + c11 * cos(th2 + th3)
    mm[3, 3] = c14 + c7 * cos(th3)
    mm[3, 4] = mm[4, 3] = c13 * cos(th3) + c12
    mm[4, 4] = c15
    s = np.diag([1e-2, 1e-2, 1, 1, 1])
    return s @ mm @ s


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (0.3, -0.5, 0.7), (-1.0, 0.4, -0.2)])
def test_paper_variant_mass_matrix_is_appendix_b(models, params, pose):
    derived = models["paper"].mass_matrix([0.0, 0.0] + list(pose))
    assert np.allclose(derived, appendix_b_mass_matrix(params, *pose), rtol=1e-12, atol=1e-15)


def test_wheel_motor_is_a_torque_pair_on_wheel_and_link1(params, models):
    """Physical: a wheel motor pushes the wheel (tau/Rw on d) and link 1 back (-tau on th1).

    Paper: tau acts on d (in cm) directly and link 1 feels nothing (README conventions).
    """
    volts = 2.0
    tau = params["right_wheel_km_nm_a"] / params["right_wheel_ra_ohm"] * volts
    f_phys = models["physical"].forcing(np.zeros(5), np.zeros(5), [volts, 0, 0, 0, 0])
    assert np.allclose(f_phys, [tau / params["rw_m"], 0, -tau, 0, 0], rtol=1e-12)
    f_paper = models["paper"].forcing(np.zeros(5), np.zeros(5), [volts, 0, 0, 0, 0])
    assert np.allclose(f_paper, [tau, 0, 0, 0, 0], rtol=1e-12)
    # Back-EMF and friction act on the wheel speed relative to link 1: the drag (forcing
    # minus that of the same robot without Ke and beta) vanishes when the wheel turns with
    # link 1 (d' = Rw th1') and not when the wheel stands still while link 1 rotates.
    frictionless = RobotModel("physical", undamped(params))
    rate = 0.7

    def drag(qd):
        return (models["physical"].forcing(np.zeros(5), qd, np.zeros(5))
                - frictionless.forcing(np.zeros(5), qd, np.zeros(5)))

    assert np.allclose(drag([params["rw_m"] * rate, params["rw_m"] * rate, rate, 0, 0]), 0, atol=1e-12)
    still = drag([0, 0, rate, 0, 0])
    damping = (params["right_wheel_km_nm_a"] * params["right_wheel_ke_v_s"] / params["right_wheel_ra_ohm"]
               + params["right_wheel_beta_nm_s"])
    assert still[0] == pytest.approx(damping * rate / params["rw_m"], rel=1e-9)
    damping_l = (params["left_wheel_km_nm_a"] * params["left_wheel_ke_v_s"] / params["left_wheel_ra_ohm"]
                 + params["left_wheel_beta_nm_s"])
    # Both stators sit on link 1: the drag of each wheel motor acts back on it.
    assert still[2] == pytest.approx(-(damping + damping_l) * rate, rel=1e-9)


@pytest.mark.slow
def test_motor_inertia_switch_changes_the_model(params, models):
    _, b_full = models["physical"].linearize()
    _, b_no_jm = RobotModel(get_variant("physical", include_motor_inertia=False), params).linearize()
    # The rotor inertia makes the wheels much heavier: less acceleration per volt.
    assert abs(b_full[5, 0]) < 0.5 * abs(b_no_jm[5, 0])


def test_unknown_variant_is_named():
    with pytest.raises(KeyError, match="unknown model variant 'segway'"):
        get_variant("segway")
