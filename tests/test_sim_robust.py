"""Monte Carlo and region of attraction: seeded, independent of the worker count, sane."""
import numpy as np
import pytest

from hostsim.studies import montecarlo
from hostsim.studies import roa
from hostsim.sim.scenario import load_scenario


def _strip(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.mark.slow
def test_montecarlo_results_do_not_depend_on_the_worker_count():
    kw = dict(runs=3, duration_s=0.5, gains_paths=("gains/physical.json",), kw0=True, seed=11)
    one = montecarlo.run_montecarlo(jobs=1, **kw)
    two = montecarlo.run_montecarlo(jobs=2, **kw)
    for label in ("physical", "physical K_w=0"):
        assert _strip(one[label]["runs"]) == _strip(two[label]["runs"])
        assert [r["index"] for r in one[label]["runs"]] == [0, 1, 2]
    # Common random numbers: each gains variant sees the same robots.
    assert [r["draw"] for r in one["physical"]["runs"]] == [r["draw"] for r in one["physical K_w=0"]["runs"]]
    # Different seeds draw different robots.
    other = montecarlo.run_montecarlo(jobs=1, **dict(kw, seed=12, kw0=False))
    assert other["physical"]["runs"][0]["draw"] != one["physical"]["runs"][0]["draw"]
    text = montecarlo.format_table(one)
    assert "physical K_w=0" in text and "runs of 0.5 s" in text


def test_montecarlo_draws_stay_in_their_ranges():
    rng = np.random.default_rng(0)
    draws = [montecarlo.draw(rng) for _ in range(300)]
    geo = np.array([[d["param_scale"][n] for n in montecarlo.GEOMETRY] for d in draws])
    mot = np.array([[d["param_scale"][n] for n in montecarlo.MOTOR] for d in draws])
    assert geo.min() >= 0.8 and geo.max() <= 1.2 and geo.max() > 1.18 and geo.min() < 0.82
    assert mot.min() >= 0.9 and mot.max() <= 1.1
    noise = [d["gyro_noise_dps"] for d in draws]
    bias = [d["gyro_bias_dps"] for d in draws]
    # Within the firmware's calibration stillness check (4 deg/s spread over 1 s).
    assert max(noise) <= 0.5 and max(abs(b) for b in bias) <= 2.0
    assert {d["extra_delay_ticks"] for d in draws} == {0, 1}
    assert max(d["jitter_s"] for d in draws) <= 0.001


def test_montecarlo_draws_the_bricks_effects_around_their_realistic_values():
    brick = load_scenario(montecarlo.BRICK_SCENARIO).brick
    rng = np.random.default_rng(0)
    draws = [montecarlo.draw(rng, brick) for _ in range(300)]
    plain = [montecarlo.draw(np.random.default_rng(0)) for _ in range(1)][0]
    # the brick is drawn after today's perturbations, which stay the same
    assert {k: v for k, v in draws[0].items() if k not in ("brick", "extra_delay_ticks", "jitter_s")} == \
        {k: v for k, v in plain.items() if k not in ("extra_delay_ticks", "jitter_s")}
    assert {d["extra_delay_ticks"] for d in draws} == {0} and {d["jitter_s"] for d in draws} == {0.0}
    back = np.array([d["brick"]["backlash_deg"] for d in draws])
    assert np.all(back >= 0.5 * np.array(brick.backlash_deg)) and np.all(back <= 1.5 * np.array(brick.backlash_deg))
    ramp = [d["brick"]["gyro_bias_ramp_dps_s"] for d in draws]
    assert min(ramp) < 0 < max(ramp) and max(abs(r) for r in ramp) <= 1.5 * brick.gyro_bias_ramp_dps_s
    senses = {tuple(v != 0 for v in d["brick"]["gyro_scale_error"]) for d in draws}
    assert senses == {(True, False), (False, True)}
    r = [d["brick"]["battery_r_ohm"] for d in draws]
    assert 0.1 <= min(r) and max(r) <= 0.3
    sc = montecarlo.scenario_for(load_scenario(montecarlo.BRICK_SCENARIO), draws[0], 2.0)
    assert sc.brick.backlash_deg == tuple(draws[0]["brick"]["backlash_deg"]) and sc.brick.timed
    assert sc.firmware_config["start_pose_rad"]["th1"] == 0.0


@pytest.mark.slow
def test_montecarlo_with_kw_zeroed_balances_the_perturbed_robots():
    """With w^ out of the loop the firmware must survive the stated uncertainty (a few runs)."""
    res = montecarlo.run_montecarlo(runs=4, duration_s=3.0, gains_paths=("gains/physical.json",), kw0=True,
                                    only_kw0=True, jobs=2, seed=3)
    s = res["physical K_w=0"]["summary"]
    assert s["success_rate"] == 1.0 and s["refused"] == 0
    assert s["peak_abs_u_v"]["max"] <= 7.6 + 1e-9


@pytest.mark.slow
def test_region_of_attraction_bisection_on_the_nonlinear_model():
    base = load_scenario("roa_base")
    res = roa.run_roa(gains_paths=("gains/physical.json",), modes=("nonlinear",), tol=0.04, angles=("th1",),
                      base=base, duration_s=3.0, jobs=2)
    rows = res["rows"]
    assert len(rows) == 2 and {r["sign"] for r in rows} == {1, -1}
    for r in rows:
        # Recovers from a tilt well beyond the balancing motion, not from lying down.
        assert 0.1 < r["max_recovered_rad"] < r["limit_rad"]
        ok = [m for m, rec in r["trials"] if rec]
        bad = [m for m, rec in r["trials"] if not rec]
        assert max(ok) == pytest.approx(r["max_recovered_rad"])
        assert min(bad) - max(ok) <= 0.04 + 1e-12
    assert "th1 -/+ rad" in roa.format_table(res)


def test_region_of_attraction_in_the_firmware_stops_at_its_stop_limit():
    # the bisection tries the firmware's stop limit first: a start pose the firmware refuses to be
    # told (tipbot_fw.config) counts as not recovered, and just inside it the firmware runs
    base = load_scenario("roa_base")
    limit = roa.angle_limits()["th1"]
    assert roa.trial(base, "gains/physical.json", False, "firmware", "th1", limit) is False
    assert roa.trial(base, "gains/physical.json", False, "firmware", "th1", -limit) is False
    assert roa.trial(base, "gains/physical.json", False, "firmware", "th1", 0.05) is True
