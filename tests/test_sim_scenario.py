"""Scenario files: every shipped one parses; malformed or unknown fields are errors naming the field."""
import glob
import json
import os

import pytest

from hostsim.sim.scenario import SCENARIO_DIR, ScenarioError, load_scenario, parse_scenario

SHIPPED = sorted(glob.glob(os.path.join(SCENARIO_DIR, "*.json")))


def test_the_paper_scenarios_are_shipped():
    names = {os.path.splitext(os.path.basename(p))[0] for p in SHIPPED}
    assert {"section7", "section8", "appendix_d", "montecarlo_base", "roa_base", "near_equilibrium"} <= names


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: os.path.basename(p))
def test_shipped_scenarios_parse(path):
    sc = load_scenario(path)
    assert os.path.exists(sc["gains"])
    assert len(sc["x0_si"]) == 10


def test_section7_is_the_printed_initial_state_in_si():
    sc = load_scenario("section7")
    # Printed with d in cm: x(0) = [2 2 0.1 0.1 0.1 0 ...], x~(0) = [1 1 0.05 0.05 0.05 1 1 1 1 1].
    assert sc["x0_si"] == pytest.approx([0.02, 0.02, 0.1, 0.1, 0.1, 0, 0, 0, 0, 0])
    assert sc["xhat0_si"] == pytest.approx([0.01, 0.01, 0.05, 0.05, 0.05, 0.01, 0.01, 1, 1, 1])
    assert sc["duration_s"] == 4.0
    assert sc["disturbances"] == [{"t_start_s": 1.5, "t_end_s": 2.0, "w_v": [1, 1, 0, 0, 0]}]


@pytest.mark.parametrize("doc, field", [
    ({"duraton_s": 3}, "duraton_s"),
    ({"duration_s": -1}, "duration_s"),
    ({"duration_s": "long"}, "duration_s"),
    ({"x0_si": [0] * 9}, "x0_si"),
    ({"x0_si": [0, 0, "a", 0, 0, 0, 0, 0, 0, 0]}, "x0_si[2]"),
    ({"x0_si": [0] * 10, "x0_paper_units": [0] * 10}, "x0_paper_units"),
    ({"xhat0_paper_units": [0] * 11}, "xhat0_paper_units"),
    ({"controllers": ["lqr"]}, "controllers"),
    ({"modes": []}, "modes"),
    ({"modes": ["linear", "linear"]}, "modes"),
    ({"plant_variant": "toy"}, "plant_variant"),
    ({"plant_method": "euler"}, "plant_method"),
    ({"param_scale": {"m9_kg": 1.1}}, "m9_kg"),
    ({"param_scale": {"m1_kg": 0}}, "param_scale.m1_kg"),
    ({"disturbances": [{"t_start_s": 2, "t_end_s": 1, "w_v": [1, 1, 0, 0, 0]}]}, "disturbances[0]"),
    ({"disturbances": [{"t_start_s": 1, "t_end_s": 2, "w_v": [1, 1, 1, 0, 0]}]}, "disturbances[0].w_v[2]"),
    ({"disturbances": [{"t_start_s": 1, "t_end": 2, "w_v": [1, 1, 0, 0, 0]}]}, "disturbances[0]"),
    ({"pushes": [{"t_s": 1}]}, "pushes[0]"),
    ({"sensors": {"gyro_nois_dps": 1}}, "sensors.gyro_nois_dps"),
    ({"sensors": {"gyro_noise_dps": -1}}, "sensors.gyro_noise_dps"),
    ({"extra_delay_ticks": 1.5}, "extra_delay_ticks"),
    ({"jitter_s": -0.001}, "jitter_s"),
    ({"seed": "x"}, "seed"),
    ({"expect": {"linear/pd": {"upright": True}}}, "expect.linear/pd"),
    ({"expect": {"linear/optimal": {"max_th": 1}}}, "expect.linear/optimal.max_th"),
    ({"expect": {"linear/optimal": {"upright": 1}}}, "expect.linear/optimal.upright"),
])
def test_malformed_fields_are_named(doc, field):
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(doc, "bad.json")
    assert "bad.json" in str(exc.value)
    assert field in str(exc.value)


def test_load_scenario_names_the_file_for_bad_json(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{not json")
    with pytest.raises(ScenarioError, match="broken.json: not valid JSON"):
        load_scenario(str(p))
    p.write_text(json.dumps({"modes": ["firmware"], "colour": "red"}))
    with pytest.raises(ScenarioError, match="unknown field 'colour'"):
        load_scenario(str(p))
