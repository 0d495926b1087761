"""The plant's speed-ups keep its numbers: the compiled derivative is bit-identical to the
model + Cholesky it replaces, and Heun at 1 kHz stays within stated bounds of RK4."""

import numpy as np
import pytest

from hostsim.model import fastdyn
from hostsim.sim.linear_sim import simulate_nonlinear
from hostsim.model.equations import RobotModel
from hostsim.world.plant import Plant, solve_spd5
from hostsim.sim.scenario import parse_scenario
from tipbot_fw.gains import load_gains
from conftest import gains_path

VARIANTS = ("paper", "physical")


def random_state(rng):
    """A state and inputs (u_th1 = 0) far and wide around the upright."""
    x = list(rng.normal(size=10) * [0.3, 0.3, 1, 1, 1, 1, 1, 3, 3, 3])
    u = list(rng.normal(size=5) * 5)
    u[2] = 0.0
    return x, u


@pytest.mark.parametrize("variant", VARIANTS)
def test_compiled_derivative_is_bit_identical(variant, params):
    model = RobotModel(variant, params)
    deriv, pre = fastdyn.compile_model(model)
    rng = np.random.default_rng(3)
    for _ in range(300):
        x, u = random_state(rng)
        m, f = model.mass_matrix_forcing(x[:5], x[5:], u)
        assert deriv(x, u, pre) == x[5:] + solve_spd5(m, f)


def test_external_force_path_agrees_with_the_fast_path(params):
    model = RobotModel("physical", params)
    x0 = [0.0, 0.01, 0.1, -0.05, 0.05, 0.0, 0.0, 0.2, 0.0, 0.0]
    a, b = Plant(model, x0), Plant(model, x0)
    u = [1.0, -0.5, 0.0, 0.3, 0.2]
    a.advance(u, 0.05)
    b.advance(u, 0.05, f_ext=[0.0] * 5)
    assert np.array_equal(a.x, b.x)


# Heun's method at 1 ms against RK4 at 1 ms over a saturated, disturbed closed-loop run: far
# below one encoder count (0.0175 rad) and one gyro LSB (0.0175 rad/s) on both models.
HEUN_BOUNDS = {"paper": (3e-4, 0.03), "physical": (2e-5, 2e-4)}   # (angles rad, rates rad/s)


@pytest.mark.parametrize("variant", VARIANTS)
def test_heun_matches_rk4_closely(variant):
    path = gains_path(variant)
    g = load_gains(path)
    base = {"duration_s": 3.0, "gains": path, "plant_variant": variant,
            "x0_si": [0, 0, 0.15, 0.1, -0.1, 0, 0, 0, 0, 0],
            "disturbances": [{"t_start_s": 1.0, "t_end_s": 2.0, "w_v": [1, 1, 0, 0.5, 0.5]}]}
    runs = {m: simulate_nonlinear(g, parse_scenario(dict(base, plant_method=m))) for m in ("rk4", "heun")}
    assert runs["rk4"].completed and np.max(np.abs(runs["rk4"].u)) == pytest.approx(7.6)
    err = np.max(np.abs(runs["heun"].x - runs["rk4"].x), axis=0)
    angles, rates = HEUN_BOUNDS[variant]
    assert err[2:5].max() < angles
    assert err[7:].max() < rates


def test_extended_derivative_adds_to_m_and_f_and_solves_extra_right_hand_sides(params):
    """deriv_ext (hostsim.world.drivetrain's): with nothing added it is deriv, bit for bit; with
    additions it solves (M + dM) q'' = F + dF and (M + dM) z = r for each extra r."""
    model = RobotModel("physical", params)
    deriv, pre = fastdyn.compile_model(model)
    ext, pre_ext = fastdyn.compile_model_ext(model)
    rng = np.random.default_rng(5)
    for _ in range(50):
        x, u = random_state(rng)
        assert ext(x, u, pre_ext, [0.0] * 20, []) == deriv(x, u, pre)
        e = list(np.abs(rng.normal(size=20)) * 1e-5)
        rhs = [list(rng.normal(size=5)), [0.0, 0.0, 0.0, 1.0, 0.0]]
        m, f = model.mass_matrix_forcing(x[:5], x[5:], u)
        low = np.zeros((5, 5))
        low[np.tril_indices(5)] = e[:15]
        mx = np.array(m).reshape(5, 5) + low + np.tril(low, -1).T
        out = ext(x, u, pre_ext, e, rhs)
        assert np.allclose(out[5:10], np.linalg.solve(mx, np.array(f) + e[15:]), rtol=1e-10, atol=1e-12)
        for j, r in enumerate(rhs):
            assert np.allclose(out[10 + 5 * j:15 + 5 * j], np.linalg.solve(mx, r), rtol=1e-10, atol=1e-12)
