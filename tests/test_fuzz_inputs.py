"""Property-based fuzzing (hypothesis) of every file format the project reads: gains, robot
configuration, scenarios, parameters and logs. Whatever the bytes, a reader either accepts the
file or raises its own error class with one line that names the file; never another exception,
never a hang. Budgets are small (make test stays fast); derandomized, so a run is repeatable."""
import copy
import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fw_support as S
from conftest import PARAMS_FILE, PHYSICAL_GAINS, REPO
from hostsim.errors import ParameterError
from hostsim.model.params import load_params
from hostsim.sim.scenario import BRICK_BOUNDS, ScenarioError, load_scenario
from tipbot_fw.record import logfile
from tipbot_fw.config import ConfigError, load_config
from tipbot_fw.gains import GainsError, load_gains

FUZZ = settings(max_examples=int(os.environ.get("TIPBOT_FUZZ_EXAMPLES", 60)), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# JSON values, including what JSON has no number for and what a float cannot hold
leaves = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 6, 10 ** 6),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                   st.sampled_from([10 ** 400, -10 ** 30, 1e308, 5e-324]))
values = st.recursive(leaves, lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
                      max_leaves=12)


def text_of(doc):
    """JSON text of doc; Python's own spellings for NaN/Infinity and huge integers."""
    return json.dumps(doc, allow_nan=True)


def one_line_error(path, exc):
    msg = str(exc)
    assert '\n' not in msg and msg.startswith(str(path)), msg


def paths_of(doc, prefix=()):
    """Every path into a nested document (dict keys, list indices)."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            for p in paths_of(v, prefix + (k,)):
                yield p
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            for p in paths_of(v, prefix + (i,)):
                yield p


NEST = '@@nest@@'


def mutate(doc, data, under=()):
    """The JSON text of doc with one value somewhere (below the path `under`) replaced by a
    fuzzed one, scaled, removed, or nested deeply."""
    doc = copy.deepcopy(doc)
    paths = [p for p in paths_of(doc) if p and p[:len(under)] == under]
    path = data.draw(st.sampled_from(paths))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    how = data.draw(st.sampled_from(['value', 'value', 'scale', 'delete', 'nest']))
    old = parent[path[-1]]
    if how == 'delete' and isinstance(parent, dict):
        del parent[path[-1]]
    elif how == 'scale' and isinstance(old, (int, float)) and not isinstance(old, bool):
        parent[path[-1]] = old * data.draw(st.sampled_from([-1, 0, 10, 100, 1e6, 1e-300, 1e300]))
    elif how == 'nest':
        parent[path[-1]] = NEST
        n = data.draw(st.integers(30, 3000))
        return text_of(doc).replace(json.dumps(NEST), '[' * n + text_of(old) + ']' * n, 1)
    else:
        parent[path[-1]] = data.draw(values)
    return text_of(doc)


def check_reader(tmp_path, raw, reader, error):
    path = tmp_path / 'fuzz.json'
    path.write_bytes(raw)
    try:
        reader(str(path))
    except error as e:
        one_line_error(path, e)


with open(PHYSICAL_GAINS) as f:
    GAINS = json.load(f)
with open(PARAMS_FILE) as f:
    PARAMS = json.load(f)
with open(os.path.join(REPO, 'scenarios', 'section8_physical.json')) as f:
    SCENARIO = json.load(f)
with open(os.path.join(REPO, 'scenarios', 'brick_realistic.json')) as f:
    BRICK_SCENARIO = json.load(f)     # the unkind brick's fields and a firmware_config
CONFIG = {'limits': {'th1_rad': 0.5}, 'filters': {'gyro_rate_cutoff_hz': 20.0}, 'wheel_radius_m': 0.034,
          'ports': {'gyro': 'in2'}, 'gyro_calibration': {'duration_s': 1.0}}


@pytest.mark.parametrize('doc, under, reader, error', [
    (GAINS, (), load_gains, GainsError), (GAINS, ('kalman',), load_gains, GainsError),
    (CONFIG, (), load_config, ConfigError), (SCENARIO, (), load_scenario, ScenarioError),
    (BRICK_SCENARIO, (), load_scenario, ScenarioError), (PARAMS, (), load_params, ParameterError)],
    ids=['gains', 'gains-kalman-block', 'config', 'scenario', 'brick scenario', 'parameters'])
@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_each_file_format_with_one_field_fuzzed(tmp_path, doc, under, reader, error, data):
    check_reader(tmp_path, mutate(doc, data, under).encode(), reader, error)


@FUZZ
@given(raw=st.one_of(st.binary(max_size=300), values.map(lambda v: text_of(v).encode())))
def test_any_bytes_as_any_json_file(tmp_path, raw):
    for reader, error in ((load_gains, GainsError), (load_config, ConfigError),
                          (load_scenario, ScenarioError), (load_params, ParameterError)):
        check_reader(tmp_path, raw, reader, error)


LOG_BYTES = {}


def a_log(tmp_path_factory, estimator, bounded=False):
    """The bytes of a short run's log with this core (made once); bounded: a run longer than
    its log_max_rows (the first 50 rows and a ring of 2 chunks of the last ones)."""
    key = (estimator, bounded)
    if key not in LOG_BYTES:
        path = str(tmp_path_factory.mktemp('fuzzlog') / 'run.log')
        sim = S.Lockstep(x0=[0, 0, 0.03, 0, 0, 0, 0, 0, 0, 0])
        from tipbot_fw.session import run_session
        keep = dict(log_max_rows=150, log_head_rows=50) if bounded else {}
        run_session(sim.dev, S.load(), S.fw_config(estimator=estimator, **keep), sim.clock, log_path=path,
                    duration_s=1.0 if bounded else 0.6, say=lambda m: None)
        with open(path, 'rb') as f:
            LOG_BYTES[key] = f.read()
    return LOG_BYTES[key]


ESTIMATORS = pytest.mark.parametrize('estimator', ['kalman', 'detector'])


@pytest.mark.parametrize('estimator, bounded', [('kalman', False), ('detector', False), ('kalman', True)])
@FUZZ
@given(data=st.data())
def test_the_log_reader_on_damaged_logs(tmp_path, tmp_path_factory, estimator, bounded, data):
    good = a_log(tmp_path_factory, estimator, bounded)
    how = data.draw(st.sampled_from(['cut', 'flip', 'splice', 'zeros']))
    raw = bytearray(good)
    if how == 'cut':
        raw = raw[:data.draw(st.integers(0, len(good)))]
    elif how == 'flip':
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= 1 << data.draw(st.integers(0, 7))
    elif how == 'splice':
        a = data.draw(st.integers(0, len(raw)))
        raw[a:a] = data.draw(st.binary(min_size=1, max_size=64))
    else:
        a = data.draw(st.integers(12, len(raw)))
        raw[a:] = bytes(len(raw) - a)
    path = tmp_path / 'fuzz.log'
    path.write_bytes(bytes(raw))
    try:
        header, rows = logfile.read_log(str(path))
    except logfile.LogFormatError as e:
        one_line_error(path, e)
        return
    # what reads is a header (a dict) and rows of its own columns; a damaged tail says so
    assert isinstance(header, dict) and rows.ndim == 2 and rows.shape[1] == len(header['columns'])
    if bytes(raw) != good:
        assert 'incomplete' in header or len(raw) > len(good) or how == 'flip'


@FUZZ
@given(raw=st.binary(max_size=400))
def test_the_log_reader_on_any_bytes(tmp_path, raw):
    for prefix in (b'', logfile.MAGIC, logfile.MAGIC + b'\x02\x00\x00\x00', logfile.MAGIC + b'\x01\x00\x00\x00'):
        path = tmp_path / 'any.log'
        path.write_bytes(prefix + raw)
        try:
            logfile.read_log(str(path))
        except logfile.LogFormatError as e:
            one_line_error(path, e)


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10 ** 6, 10 ** 6),
                    st.sampled_from([0, 0.0005, 0.005, 0.0051, 1, 1.0001, 90, 100, 101, 3600, 1e300, -1e-300]))


@FUZZ
@given(data=st.data())
def test_brick_fields_take_only_physical_values(tmp_path, data):
    # every brick field (hostsim.sim.scenario.BRICK_BOUNDS) with any value: refused naming the
    # field, or accepted and within its bound (a range ordered, a sign only where it has one)
    field, kind, bound = data.draw(st.sampled_from(BRICK_BOUNDS))
    n = {'range': 2, 'pair': 2, 'motors': 4}.get(kind)
    value = data.draw(st.one_of(values, st.lists(numbers, min_size=n, max_size=n) if n else numbers))
    path = tmp_path / 'b.json'
    path.write_text(text_of({'modes': ['firmware'], 'brick': {field: value}}))
    try:
        sc = load_scenario(str(path))
    except ScenarioError as e:
        one_line_error(path, e)
        assert ': field ' not in str(e) or str(e).startswith('%s: field brick.%s' % (path, field)), str(e)
        return
    got = getattr(sc.brick, field)
    if kind == 'flag':
        assert isinstance(got, bool)
        return
    got = list(got) if n else [got]
    lo = -bound if kind in ('pair', 'signed') else 0
    assert all(lo <= v <= bound for v in got), got
    if kind == 'range':
        assert got[0] <= got[1]


@FUZZ
@given(data=st.data())
def test_what_a_scenario_tells_the_firmware_is_checked_when_read(tmp_path, data):
    # a scenario's firmware_config, fuzzed where a config is: refused naming firmware_config.<field>
    # (or, for what JSON cannot hold, the place in the file), or what the simulation builds from it
    # is a configuration the firmware accepts
    from hostsim.sim.firmware_build import firmware_config
    path = tmp_path / 'b.json'
    path.write_text('{"modes": ["firmware"], "firmware_config": %s}' % mutate(CONFIG, data))
    try:
        sc = load_scenario(str(path))
    except ScenarioError as e:
        one_line_error(path, e)
        assert ': field ' not in str(e) or str(e).startswith('%s: field firmware_config' % path), str(e)
        return
    assert firmware_config(sc, 0.034)['ports']['gyro'] in ('in1', 'in2', 'in3', 'in4')


def test_the_fuzzed_good_files_are_accepted():
    # not vacuous: the documents the fuzzers mutate are valid as they are
    assert load_gains(PHYSICAL_GAINS).ts_s == 0.005
    assert load_params(PARAMS_FILE)['rw_m'] == 0.034
    assert np.isfinite(load_scenario(os.path.join(REPO, 'scenarios', 'section8_physical.json')).duration_s)
    assert load_scenario(os.path.join(REPO, 'scenarios', 'brick_realistic.json')).brick.timed


def _log_with(path, header_text, rows):
    """A version-1 log (one CRC over everything: docs/log-format.md) around any header text."""
    import struct
    import zlib
    text = header_text.encode()
    body = np.ascontiguousarray(rows, dtype='<f8')
    counts = struct.pack('<IIIQ', 1, len(text), body.shape[1], body.shape[0])
    crc = zlib.crc32(counts + text + body.tobytes()) & 0xffffffff
    with open(path, 'wb') as f:
        f.write(logfile.MAGIC + counts + text + body.tobytes() + struct.pack('<I', crc))


@ESTIMATORS
@FUZZ
@given(data=st.data())
def test_replay_and_identify_on_logs_with_a_valid_crc_and_bad_content(tmp_path, tmp_path_factory, estimator, data):
    # the CRC is right, what it protects is not: every field of the header and every value of
    # the rows is fair game; the host tools answer with exit status 2 and one line, or replay
    from hostsim.logs import identify, replay
    good = tmp_path / 'good.log'
    good.write_bytes(a_log(tmp_path_factory, estimator))
    header, rows = logfile.read_log(str(good))
    rows = rows.copy()
    if data.draw(st.booleans()):
        i, j = data.draw(st.integers(0, len(rows) - 1)), data.draw(st.integers(0, rows.shape[1] - 1))
        rows[i, j] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -8.0, 1e-6, 1e300]))
    path = tmp_path / 'bad.log'
    _log_with(str(path), mutate(header, data), rows)
    for main in (replay.main, identify.main):
        try:
            code = main([str(path), '--no-plots'])
        except SystemExit as e:      # argparse
            code = e.code
        assert code in (0, 1, 2)
