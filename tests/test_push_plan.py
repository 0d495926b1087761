"""Plans started after the push (hostsim.studies.push_plan): what a recovery the brick starts a
tick or more after a push on link 3 can still hold, on the physical gains' model, filter and law."""
import numpy as np
import pytest

from conftest import gains_path
from hostsim.studies import push_limit as pl
from hostsim.studies import push_plan as pp

pytestmark = pytest.mark.slow   # linear programs of a few seconds: not in make test-fast


@pytest.fixture(scope="module")
def setup():
    d = pl.load_design(gains_path("physical"))
    kal = d["kalman"]
    ac, bc = pp.continuous_model(d)
    return d, kal, ac, bc


def test_without_a_delay_the_delayed_model_is_the_gains_own(setup):
    d, _, ac, bc = setup
    ad, bd = pp.delayed_model(ac, bc, d["ts_s"], 0.0)
    assert np.allclose(ad[:10, :10], d["A"], atol=1e-9) and np.allclose(bd[:10], d["B"], atol=1e-9)
    assert np.allclose(ad[:10, 10:], 0.0, atol=1e-12)     # nothing of the last input lands late
    ad, bd = pp.delayed_model(ac, bc, d["ts_s"], 0.002)
    assert np.allclose(bd[:10] + ad[:10, 10:], d["B"], atol=1e-9)   # the same input, split in time
    assert np.abs(ad[:10, 10:]).max() > 0.1 * np.abs(d["B"]).max()


def test_the_loop_response_is_the_push_then_the_laws_reaction(setup):
    d, kal, ac, bc = setup
    ad, bd = pp.delayed_model(ac, bc, d["ts_s"], 0.0)
    resp = pp.loop_response(ad, bd, kal, d["x_push"], 3)
    assert np.allclose(resp[0][0], d["x_push"]) and not resp[0][1].any()
    assert np.allclose(resp[1][0], d["A"] @ d["x_push"])     # no input before the first read
    t3, u3, xh3, _ = resp[3]
    # the estimate lags the push: after 3 ticks the filter has seen 60 % of link 3's speed, and link
    # 2's the wrong way round (its model has no push: the law meanwhile acts on that)
    assert 0 < xh3[9] < 0.7 * t3[9] and xh3[8] < 0 < t3[8]
    assert np.allclose(u3, -kal.K @ xh3)


def test_a_plan_scaled_down_is_feasible_for_a_smaller_push(setup):
    d, kal, ac, bc = setup
    ad, bd = pp.delayed_model(ac, bc, d["ts_s"], pp.DELAY_S)
    resp = pp.loop_response(ad, bd, kal, d["x_push"], 2)
    s0 = np.concatenate([resp[2][0], resp[1][1]])
    limits = pl.stop_limits()
    pmax, u, s = pp.plan_from(pl._solve, ad, bd, d["K"], s0, d["ts_s"], d["u_max_v"], limits)
    assert 0.2 < pmax < pl.max_push(d, 2.0, "recover")[0]     # below the bound from the push itself
    for scale in (1.0, 0.8, 0.3):
        us, ss = scale * u, scale * s
        assert np.abs(us).max() <= pp.PLAN_INPUT_FRACTION * d["u_max_v"] * (1 + 1e-7)
        for k in range(len(us)):
            assert np.allclose(ss[k + 1], ad @ ss[k] + bd @ us[k], atol=1e-7)
        assert all(np.abs(ss[:, i]).max() <= lim + 1e-7 for i, lim in zip(pp.ANGLES, limits))
        # the law takes over at the end without saturating (the hand-over's inputs, simulated)
        kd = np.hstack([d["K"], np.zeros((4, 4))])
        x, peak = ss[-1], 0.0
        for _ in range(int(round(pp.HANDOVER_S / d["ts_s"]))):
            uk = -kd @ x
            peak = max(peak, np.abs(uk).max())
            x = ad @ x + bd @ uk
        assert peak <= pp.END_INPUT_FRACTION * d["u_max_v"] * (1 + 1e-6)
        assert np.abs(x[2:5]).max() < 0.03 * scale      # upright again, rolling back to its place


def test_each_tick_of_detection_costs_the_bound(setup):
    d = setup[0]
    rows = pp.late_bounds(pl._solve, d, d["kalman"], pl.stop_limits(), delays_s=(pp.DELAY_S,), late_ticks=2)
    p = [r["recoverable_n_s"] for r in rows]
    bound = pl.max_push(d, 2.0, "recover")[0]
    assert p[0] <= bound + 1e-9 and p[0] > p[1] > p[2] > 0.9 * bound
    assert p[0] - p[1] > 0.01 * bound                       # a tick later is at least 1 % of the bound
