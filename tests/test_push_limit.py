"""The push limit (hostsim.studies.push_limit): the LP bounds on the largest recoverable push on
link 3, against the simulator's push and the shipped law, on the physical gains' model."""
import json

import numpy as np
import pytest

from conftest import gains_path
from hostsim.studies import push_limit as pl
from hostsim.world.plant import Plant, link_push_impulse

pytestmark = pytest.mark.slow   # real processes or long studies: not in make test-fast


@pytest.fixture(scope="module")
def design():
    return pl.load_design(gains_path("physical"))


def test_the_push_state_is_the_one_the_simulator_applies(design):
    plant = Plant(design["model"])
    plant.apply_impulse(link_push_impulse(plant.model, plant.x[:5], 3, 0.2))
    assert np.allclose(plant.x_si, 0.2 * design["x_push"], rtol=1e-9, atol=1e-12)
    assert design["x_push"][9] > design["x_push"][8] > design["x_push"][7] > 0   # the top link swings most


def test_the_bounds_close_in_as_the_horizon_grows(design):
    rec = [pl.max_push(design, h, "recover")[0] for h in (0.5, 1.0, 2.0)]
    loss = [pl.max_push(design, h, "loss")[0] for h in (0.5, 1.0, 2.0)]
    assert rec[0] < rec[1] <= rec[2] + 1e-9 and loss[0] >= loss[1] - 1e-9 >= loss[2] - 2e-9
    assert all(r <= l + 1e-9 for r, l in zip(rec, loss))
    assert rec[0] < 0.95 * loss[0]                         # a short horizon is far from the answer
    assert loss[2] - rec[2] < 0.01 * loss[2]               # 2 s settles it


def test_the_recoverable_plan_reaches_rest_within_the_input_limit(design):
    p, u, x = pl.max_push(design, 1.0, "recover", (0.6, 1.2, 1.2))
    assert np.max(np.abs(u)) <= design["u_max_v"] * (1 + 1e-7)
    a, b = design["A"], design["B"]
    for k in range(len(u)):           # the states are the model's own trajectory from the push
        assert np.allclose(x[k + 1], a @ x[k] + b @ u[k], atol=1e-7)
    assert np.allclose(x[0], p * design["x_push"]) and np.max(np.abs(x[-1, 2:])) < 1e-6


def test_the_bound_grows_with_the_input_limit_in_proportion(design):
    lo = pl.max_push(dict(design, u_max_v=6.0), 1.0, "recover")[0]
    hi = pl.max_push(design, 1.0, "recover")[0]
    assert hi > lo and hi / lo == pytest.approx(design["u_max_v"] / 6.0, rel=1e-3)


def test_tighter_joint_limits_lower_the_bound(design):
    # the firmware's stop limits do not bind (as if there were none); 0.2 rad on the joints does
    loose = pl.max_push(design, 1.0, "recover", (0.6, 1.2, 1.2))[0]
    assert pl.max_push(design, 1.0, "recover", (10.0, 10.0, 10.0))[0] == pytest.approx(loose, rel=1e-4)
    assert loose <= pl.max_push(design, 1.0, "recover")[0] + 1e-9     # at rest at N asks more
    tight, _, x = pl.max_push(design, 1.0, "recover", (0.6, 0.2, 0.2))
    assert tight < 0.98 * loose and np.max(np.abs(x[:, 3:5])) <= 0.2 + 1e-7


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_shipped_law_recovers_less_than_the_bound_and_fails_beyond_it(design, sign):
    lqr = pl.lqr_linear_limit(design, sign, tol=2e-3)
    loss = pl.max_push(design, 0.5, "loss", sign=sign)[0]
    assert 0.1 < lqr <= loss
    assert not pl.lqr_linear_recovers(dict(design, x_push=sign * design["x_push"]), 1.05 * loss)


def test_the_command_writes_both_bounds_per_direction(tmp_path, capsys):
    assert pl.main(["--gains", gains_path("physical"), "--horizons", "0.5", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "push_limit.json") as f:
        res = json.load(f)
    assert {(r["sign"], r["joint_limits"]) for r in res["rows"]} == {(1, False), (1, True), (-1, False), (-1, True)}
    assert all(r["recoverable_n_s"] <= r["certain_loss_n_s"] + 1e-9 for r in res["rows"])
    # a plan started after the push holds less than the bound, the later the less
    late = [r["recoverable_n_s"] for r in res["late"] if r["delay_s"] > 0]
    assert len(late) == 4 and all(a > b for a, b in zip(late, late[1:]))
    assert late[0] <= min(r["certain_loss_n_s"] for r in res["rows"]) + 1e-9     # never beyond certain loss
    out = capsys.readouterr().out
    assert "certain loss N s" in out and "plan starts (ticks after the push)" in out


def test_a_bad_gains_file_is_one_line_naming_it(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"ts_s": 0.005}')
    assert pl.main(["--gains", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "schema_version" in err


def test_near_the_bound_the_plan_recovers_the_nonlinear_robot_where_the_lqr_law_falls(design):
    v = pl.validate_nonlinear(design, 2.0, settle_s=0.5)
    assert v["push_n_s"] == pytest.approx(pl.VALIDATE_FRACTION * v["recoverable_n_s"])
    assert v["push_n_s"] > pl.lqr_linear_limit(design, tol=2e-3)      # beyond what the shipped law takes
    assert v["plan then LQR"]["recovered"] and not v["LQR alone"]["recovered"]
