"""Scenario files: every shipped one parses; malformed or unknown fields are errors naming the field."""
import glob
import json
import os
import re

import pytest

from hostsim.sim.scenario import SCENARIO_DIR, Disturbance, ScenarioError, load_scenario, parse_scenario

SHIPPED = sorted(glob.glob(os.path.join(SCENARIO_DIR, "*.json")))


def test_the_paper_scenarios_are_shipped():
    names = {os.path.splitext(os.path.basename(p))[0] for p in SHIPPED}
    assert {"section7", "section8", "appendix_d", "montecarlo_base", "roa_base", "near_equilibrium"} <= names


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: os.path.basename(p))
def test_shipped_scenarios_parse(path):
    sc = load_scenario(path)
    assert os.path.exists(sc.gains)
    assert len(sc.x0_si) == 10


def test_section7_is_the_printed_initial_state_in_si():
    sc = load_scenario("section7")
    # Printed with d in cm: x(0) = [2 2 0.1 0.1 0.1 0 ...], x~(0) = [1 1 0.05 0.05 0.05 1 1 1 1 1].
    assert sc.x0_si == pytest.approx((0.02, 0.02, 0.1, 0.1, 0.1, 0, 0, 0, 0, 0))
    assert sc.xhat0_si == pytest.approx((0.01, 0.01, 0.05, 0.05, 0.05, 0.01, 0.01, 1, 1, 1))
    assert sc.duration_s == 4.0
    assert sc.disturbances == (Disturbance(1.5, 2.0, (1, 1, 0, 0, 0)),)


@pytest.mark.parametrize("doc, message", [
    ({"duraton_s": 3}, "field duraton_s is unknown"),
    ({"duration_s": -1}, "field duration_s must be a number in (0, 600.0], got -1"),
    ({"duration_s": "long"}, "field duration_s must be a number in (0, 600.0], got 'long'"),
    ({"x0_si": [0] * 9}, "field x0_si must be a list of 10 numbers, got [0, 0, 0, 0, 0, 0, 0, 0, 0]"),
    ({"x0_si": [0, 0, "a", 0, 0, 0, 0, 0, 0, 0]}, "field x0_si[2] must be a number in [-3.2, 3.2], got 'a'"),
    ({"x0_si": [0] * 10, "x0_paper_units": [0] * 10}, "field x0_paper_units conflicts with x0_si: give one"),
    ({"xhat0_paper_units": [0] * 11}, "field xhat0_paper_units must be a list of 10 numbers, got [0, 0, 0, 0, 0, 0, "
                                      "0, 0, 0, 0, 0]"),
    ({"controllers": ["lqr"]}, "field controllers must be a non-empty list of optimal, pd, got ['lqr']"),
    ({"modes": []}, "field modes must be a non-empty list of linear, nonlinear, firmware, got []"),
    ({"modes": ["linear", "linear"]}, "field modes lists an entry twice: ['linear', 'linear']"),
    ({"plant_variant": "toy"}, "field plant_variant must be one of 'paper', 'physical', got 'toy'"),
    ({"plant_method": "euler"}, "field plant_method must be one of 'rk4', 'heun', got 'euler'"),
    ({"param_scale": {"m9_kg": 1.1}}, "field param_scale.m9_kg is unknown"),
    ({"param_scale": {"m1_kg": 0}}, "field param_scale.m1_kg must be a number in [0.01, 100.0], got 0"),
    ({"disturbances": [{"t_start_s": 2, "t_end_s": 1, "w_v": [1, 1, 0, 0, 0]}]},
     "field disturbances[0] ends before it starts"),
    ({"disturbances": [{"t_start_s": 1, "t_end_s": 2, "w_v": [1, 1, 1, 0, 0]}]},
     "field disturbances[0].w_v[2] must be 0 (link 1 has no motor)"),
    ({"disturbances": [{"t_start_s": 1, "t_end": 2, "w_v": [1, 1, 0, 0, 0]}]},
     "field disturbances[0] must be an object with exactly t_start_s, t_end_s, w_v, got "
     "{'t_start_s': 1, 't_end': 2, 'w_v': [1, 1, 0, 0, 0]}"),
    ({"pushes": [{"t_s": 1}]}, "field pushes[0] must be an object with exactly t_s, th1_dot_rad_s, got {'t_s': 1}"),
    ({"sensors": {"gyro_nois_dps": 1}}, "field sensors.gyro_nois_dps is unknown"),
    ({"sensors": {"gyro_noise_dps": -1}}, "field sensors.gyro_noise_dps must be a number in [0, 50], got -1"),
    ({"extra_delay_ticks": 1.5}, "field extra_delay_ticks must be an integer in [0, 100], got 1.5"),
    ({"jitter_s": -0.001}, "field jitter_s must be a number in [0, 0.05], got -0.001"),
    ({"seed": "x"}, "field seed must be an integer in [0, 4294967295], got 'x'"),
    ({"expect": {"linear/pd": {"upright": True}}},
     "field expect.linear/pd names no run of this scenario (runs: firmware/optimal, linear/optimal)"),
    ({"expect": {"linear/optimal": {"max_th": 1}}}, "field expect.linear/optimal.max_th is unknown"),
    ({"expect": {"linear/optimal": {"upright": 1}}}, "field expect.linear/optimal.upright must be true or false, got 1"),
    ({"pushes": [{"t_s": 1, "link": 4, "impulse_n_s": 0.1}]}, "field pushes[0].link must be one of 1, 2, 3, got 4"),
    ({"brick": {"backlash": [3, 3, 3, 0]}}, "field brick.backlash is unknown"),
    ({"brick": {"backlash_deg": [3, 3, 3]}}, "field brick.backlash_deg must be a list of 4 numbers, got [3, 3, 3]"),
    ({"brick": {"friction_deadband_pct": [4, 4, -4, 10]}},
     "field brick.friction_deadband_pct[2] must be a number in [0, 100], got -4"),
    ({"brick": {"tacho_access_s": [0.0005, 0.0003]}},
     "field brick.tacho_access_s must be [lo, hi] with 0 <= lo <= hi, got [0.0005, 0.0003]"),
    ({"brick": {"gyro_scale_error": [-0.02, 0.7]}}, "field brick.gyro_scale_error[1] must be a number in [-0.5, 0.5], got 0.7"),
    ({"brick": {"encoder_truncate": 1}}, "field brick.encoder_truncate must be true or false, got 1"),
    ({"brick": {"sources": {"backlash": "x"}}}, "field brick.sources.backlash names no brick field"),
    ({"brick": {"compute_s": [0.0007, 0.0009]}, "jitter_s": 0.001},
     "field jitter_s must be 0.0 with the brick's timing (brick.*_access_s, compute_s, late wakes, stalls replace it)"),
    ({"brick": {"compute_s": [0.0007, 0.0009]}, "io_latency_s": 0.002},
     "field io_latency_s does not apply with the brick's timing (each duty lands at its own write)"),
    ({"firmware_config": []}, "field firmware_config must be an object, got []"),
    # physical bounds of the brick's fields, the impulse pushes and what the firmware is told
    ({"brick": {"stall_s": [0.01, 2]}}, "field brick.stall_s[1] must be a number in [0, 1], got 2"),
    ({"brick": {"tacho_access_s": [0.0003, 0.05]}},
     "field brick.tacho_access_s[1] must be a number in [0, 0.005], got 0.05"),
    ({"brick": {"gyro_bias_ramp_dps_s": 1e300}},
     "field brick.gyro_bias_ramp_dps_s must be a number in [-1, 1], got 1e+300"),
    ({"brick": {"backlash_deg": [3, 3, 3, float("nan")]}},
     "field brick.backlash_deg[3] must be a number in [0, 90], got nan"),
    ({"brick": {"battery_r_ohm": -0.2}}, "field brick.battery_r_ohm must be a number in [0, 5], got -0.2"),
    ({"pushes": [{"t_s": 1, "link": 3, "impulse_n_s": 1e300}]},
     "field pushes[0].impulse_n_s must be a number in [-5.0, 5.0], got 1e+300"),
    ({"firmware_config": {"colour": "red"}}, "field firmware_config.colour is unknown"),
    ({"firmware_config": {"limits": 3}}, "field firmware_config.limits must be an object, got 3"),
    ({"firmware_config": {"limits": {"max_lost_s": 1000}}},
     "field firmware_config.limits.max_lost_s must be a number in (0, 0.1], got 1000"),
    ({"x0_si": [0, 0, 0.7, 0, 0, 0, 0, 0, 0, 0]},
     "field firmware_config.start_pose_rad.th1 is 0.7 rad, beyond limits.th1_rad = 0.6: the run would stop at its "
     "first tick"),
])
def test_malformed_fields_are_named(doc, message):
    with pytest.raises(ScenarioError, match="^" + re.escape("bad.json: " + message) + "$"):
        parse_scenario(doc, "bad.json")


def test_load_scenario_names_the_file_for_bad_json(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{not json")
    with pytest.raises(ScenarioError, match="broken.json: not valid JSON"):
        load_scenario(str(p))
    p.write_text(json.dumps({"modes": ["firmware"], "colour": "red"}))
    with pytest.raises(ScenarioError, match="broken.json: field colour is unknown$"):
        load_scenario(str(p))


def test_firmware_config_is_checked_only_for_what_the_firmware_is_told():
    # a linear-only scenario may start beyond the firmware's stop limits; told another pose, so may
    # a firmware run (the brick_realistic way: released tilted, told upright)
    tilted = [0, 0, 0.7, 0, 0, 0, 0, 0, 0, 0]
    assert parse_scenario({"x0_si": tilted, "modes": ["linear"]}, "ok.json").x0_si[2] == 0.7
    sc = parse_scenario({"x0_si": tilted, "firmware_config": {"start_pose_rad": {"th1": 0.0}}}, "ok.json")
    assert sc.firmware_config == {"start_pose_rad": {"th1": 0.0}}

