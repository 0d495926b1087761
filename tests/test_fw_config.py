"""tipbot_fw.config: defaults, --config overrides, and error messages naming file and field."""
import json
import re

import pytest

from tipbot_fw.config import ConfigError, DEFAULT_PATH, config_from_overrides, load_config


def write(tmp_path, text, name='robot.json'):
    p = tmp_path / name
    p.write_text(text if isinstance(text, str) else json.dumps(text))
    return str(p)


def test_defaults_are_the_documented_robot():
    c = load_config()
    assert c['ports'] == {'right_wheel': 'outA', 'left_wheel': 'outB', 'joint2': 'outC',
                          'joint3': 'outD', 'gyro': 'in2', 'ir_remote': None}
    assert c['drivers']['joint3'] == 'lego-ev3-m-motor'
    assert c['drivers']['gyro'] == 'lego-ev3-gyro'
    assert c['wheel_radius_m'] == 0.034
    assert c['limits']['th1_rad'] == 0.6 and c['limits']['min_battery_v'] == 6.5


def test_override_replaces_only_the_given_fields(tmp_path):
    path = write(tmp_path, {'polarity': {'joint3': -1}, 'limits': {'th1_rad': 0.4}, 'gyro_sign': -1})
    c = load_config(path)
    assert c['polarity'] == {'right_wheel': 1, 'left_wheel': 1, 'joint2': 1, 'joint3': -1}
    assert c['limits']['th1_rad'] == 0.4
    assert c['limits']['min_battery_v'] == load_config()['limits']['min_battery_v']
    assert c['gyro_sign'] == -1
    # the defaults themselves are untouched by a merge
    assert load_config()['polarity']['joint3'] == 1


def test_null_bias_time_constant_disables_tracking(tmp_path):
    assert load_config(write(tmp_path, {'gyro_bias_time_constant_s': None}))['gyro_bias_time_constant_s'] is None


@pytest.mark.parametrize('override, message', [
    ({'limits': {'th1_limit': 1.0}}, 'field limits.th1_limit is unknown$'),
    ({'colour': 'red'}, 'field colour is unknown$'),
    ({'limits': 0.6}, 'field limits must be an object, got 0.6'),
    ({'polarity': {'right_wheel': 2}}, 'field polarity.right_wheel must be one of 1, -1, got 2'),
    ({'polarity': {'right_wheel': True}}, 'field polarity.right_wheel must be one of 1, -1, got True'),
    ({'wheel_radius_m': 0}, r'field wheel_radius_m must be a number in \(0.005, 0.1\], got 0'),
    ({'wheel_radius_m': '0.034'}, "field wheel_radius_m must be a number in .*got '0.034'"),
    ({'limits': {'max_consecutive_overruns': 2.5}}, 'field limits.max_consecutive_overruns must be an integer'),
    # the overrun stop: a window of a few periods to 2 s, a lost time above 0 and below any delay margin
    ({'limits': {'overrun_window_s': 0.01}}, r'field limits.overrun_window_s must be a number in \[0.02, 2.0\], got 0.01'),
    ({'limits': {'overrun_window_s': 5}}, r'field limits.overrun_window_s must be a number in \[0.02, 2.0\], got 5'),
    ({'limits': {'max_lost_s': 0}}, r'field limits.max_lost_s must be a number in \(0, 0.1\], got 0'),
    ({'limits': {'max_lost_s': 1e6}}, r'field limits.max_lost_s must be a number in \(0, 0.1\], got 1000000.0'),
    ({'limits': {'max_lost_s': None}}, r'field limits.max_lost_s must be a number in \(0, 0.1\], got None'),
    ({'limits': {'max_saturated_s': 0.1}}, r'field limits.max_saturated_s must be a number in \[0.25, 5.0\], got 0.1'),
    ({'limits': {'max_saturated_s': None}}, r'field limits.max_saturated_s must be a number in \[0.25, 5.0\], got None'),
    ({'limits': {'max_lost_s': 0.06, 'overrun_window_s': 0.1}},
     r'field limits.max_lost_s is 0.06 s, more than half of limits.overrun_window_s = 0.1 s: a loop running at '
     r'half its rate would never be stopped$'),
    ({'ports': {'gyro': 'outA'}}, "field ports.gyro must be one of 'in1', 'in2', 'in3', 'in4', got 'outA'"),
    ({'ports': {'joint2': 'outA'}}, 'field ports.right_wheel is outA, the port of another motor too$'),
    ({'drivers': {'gyro': ''}}, 'field drivers.gyro must be a non-empty string'),
    ({'stop_action': 'hold'}, "field stop_action must be one of 'coast', 'brake', got 'hold'"),
    ({'realtime_priority': 100}, 'field realtime_priority must be an integer in'),
    ({'log_head_rows': -1}, r'field log_head_rows must be an integer in \[0, 720000\], got -1$'),
    ({'log_head_rows': 10.5}, r'field log_head_rows must be an integer in \[0, 720000\], got 10.5$'),
    # the warning within what a battery reads, and before the refusal to start
    ({'limits': {'warn_battery_v': 20}}, r'field limits.warn_battery_v must be a number in \[5.0, 9.0\], got 20'),
    ({'limits': {'warn_battery_v': 6.0}}, 'field limits.warn_battery_v is 6.0 V, below limits.min_battery_v = 6.5 V'),
])
def test_invalid_fields_are_named_with_the_file(tmp_path, override, message):
    path = write(tmp_path, override)
    with pytest.raises(ConfigError, match=re.escape(path) + ': ' + message):
        load_config(path)


def test_non_finite_number_is_refused(tmp_path):
    path = write(tmp_path, '{"filters": {"gyro_rate_cutoff_hz": NaN}}')
    with pytest.raises(ConfigError, match=r'field filters.gyro_rate_cutoff_hz is NaN, not a finite number'):
        load_config(path)


def test_malformed_json_names_the_file(tmp_path):
    path = write(tmp_path, '{"limits": {"th1_rad": 0.5,}}')
    with pytest.raises(ConfigError, match=re.escape(path) + ': not valid JSON'):
        load_config(path)


def test_top_level_must_be_an_object(tmp_path):
    path = write(tmp_path, '[1, 2]')
    with pytest.raises(ConfigError, match=re.escape(path) + ': must be a JSON object'):
        load_config(path)


def test_missing_file(tmp_path):
    path = str(tmp_path / 'nope.json')
    with pytest.raises(ConfigError, match=re.escape(path) + ': cannot read'):
        load_config(path)


def test_default_file_is_complete_and_valid():
    with open(DEFAULT_PATH) as f:
        assert config_from_overrides({}) == json.load(f)


def test_the_overrun_stop_of_earlier_versions_still_loads_with_a_note(tmp_path):
    # an owner's config.json from before the lost-time stop: it loads, the field is ignored, and a
    # note (one line, naming the file and the field) says so
    path = write(tmp_path, {'limits': {'th1_rad': 0.5, 'max_consecutive_overruns': 5}})
    notes = []
    c = load_config(path, notes)
    assert c['limits']['th1_rad'] == 0.5
    assert 'max_consecutive_overruns' not in c['limits']
    assert c['limits']['max_lost_s'] == load_config()['limits']['max_lost_s']
    assert len(notes) == 1 and '\n' not in notes[0]
    assert notes[0].startswith(path + ': field limits.max_consecutive_overruns is no longer used')
    assert load_config(path)['limits'] == c['limits']        # without a list for the notes too


def test_a_scenario_firmware_config_names_the_deprecated_field_in_its_place():
    notes = []
    config_from_overrides({'limits': {'max_consecutive_overruns': 7}}, 'scen.json', prefix='firmware_config.',
                          notes=notes)
    assert notes == ['scen.json: field firmware_config.limits.max_consecutive_overruns is no longer used (the '
                     'overrun stop is now limits.max_lost_s within limits.overrun_window_s; see docs/realistic-brick.md): ignored']
