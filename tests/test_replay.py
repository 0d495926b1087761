"""`python -m hostsim replay`: logs the firmware wrote in the simulator replay exactly through
the firmware's own code; other gains show what they would have commanded; logs that are
truncated, corrupted or from another version are refused with a message saying so."""
import json
import os
import shutil
import struct
import zlib

import numpy as np
import pytest

from hostsim.sim import firmware_run
from hostsim.logs import replay
from hostsim.sim.scenario import parse_scenario
from tipbot_fw.record import logfile
from conftest import PAPER_GAINS, PHYSICAL_GAINS
from tipbot_fw import vocabulary

# Small gyro noise and a push: the readings, estimates and inputs move (not a trivial log).
SCENARIO = {"name": "replay-test", "duration_s": 1.5, "sensors": {"gyro_noise_dps": 0.3, "gyro_bias_dps": 0.7},
            "pushes": [{"t_s": 0.2, "th1_dot_rad_s": 0.05}], "seed": 7}


def simulate(path, sysfs=True, config_overrides=None, result=None):
    sc = parse_scenario(dict(SCENARIO, gains=PHYSICAL_GAINS))
    run = firmware_run.run_firmware(sc, log_path=str(path), sysfs=sysfs, config_overrides=config_overrides)
    if result is not None:
        result.append(run)
    return str(path)


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    """A log the firmware wrote while balancing the simulated robot through the fake EV3."""
    return simulate(tmp_path_factory.mktemp("sim") / "tipbot-sim.log")


def col(header, name):
    return [c["name"] for c in header["columns"]].index(name)


def run_main(capsys, *argv):
    code = replay.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_raw(path, header, rows, version=1, columns=None):
    """A log file in format version 1 (docs/log-format.md: still read), built without
    logfile.write_log: magic, <IIIQ (version, header length, columns, rows), header JSON, float64
    rows, CRC32."""
    header = dict(header)
    if columns is not None:
        header["columns"] = columns
    text = json.dumps(header, sort_keys=True).encode("utf-8")
    body = np.ascontiguousarray(rows, dtype="<f8")
    counts = struct.pack("<IIIQ", version, len(text), body.shape[1], body.shape[0])
    crc = zlib.crc32(counts + text + body.tobytes()) & 0xffffffff
    with open(path, "wb") as f:
        f.write(logfile.MAGIC + counts + text + body.tobytes() + struct.pack("<I", crc))
    return str(path)


# ------------------------------------------------------------------ exact replay
@pytest.mark.slow
def test_a_simulated_log_replays_exactly_with_plots(sim_log, tmp_path, capsys):
    code, out, err = run_main(capsys, sim_log, "--out", tmp_path / "plots")
    assert code == 0, err
    assert "replays exactly" in out
    assert "replay with the logged gains (%s)" % PHYSICAL_GAINS in out
    for what in ("inputs", "estimates"):
        png = tmp_path / "plots" / ("tipbot-sim-%s.png" % what)
        assert png.stat().st_size > 10000
    r = replay.replay_log(sim_log)
    assert r.exact and r.max_diff == 0.0            # the Kalman core's integers: bit for bit
    # not vacuous: the run moved, the inputs varied, and every group was compared
    rows, h = r.rows, r.header
    assert len(rows) > 100
    assert np.ptp(rows[:, col(h, "duty_r")]) > 1 and np.ptp(rows[:, col(h, "xi_th1")]) > 1e-3
    labels = [label for label, _ in r.diffs]
    assert {"filter state xi", "duties", "flags"} <= set(labels)


def test_a_log_with_a_stall_replays_exactly_through_the_periods_the_core_predicted(tmp_path):
    # one 70 ms stall at 1.6 s (0.5 s into the balancing): the core predicted through the periods
    # it missed, and the replay, reading their count from the flags, does the same to the bit
    sc = parse_scenario(dict(SCENARIO, gains=PHYSICAL_GAINS, brick={"single_stall_s": 0.07, "single_stall_at_s": 1.6}))
    path = str(tmp_path / "stall.log")
    firmware_run.run_firmware(sc, log_path=path, sysfs=True)
    r = replay.replay_log(path)
    skipped = (r.rows[:, col(r.header, "flags")].astype(int) >> vocabulary.SKIP_SHIFT) & vocabulary.SKIP_MAX
    assert 12 <= skipped.max() <= 14 and r.header["loop"]["skipped_periods"] >= skipped.max()
    assert r.exact and r.max_diff == 0.0
    # and the prediction mattered: without it the rows after the stall differ
    from tipbot_fw.cores.kalman import KalmanCore
    saved = KalmanCore.skip
    try:
        KalmanCore.skip = lambda self, m: None
        assert not replay.replay_log(path).exact
    finally:
        KalmanCore.skip = saved


def test_a_detector_log_replays_exactly_too(tmp_path):
    r = replay.replay_log(simulate(tmp_path / "det.log", sysfs=False, config_overrides={"estimator": "detector"}))
    assert r.exact, r.diffs
    assert {"estimates x~", "inputs u", "signal chain y", "duties"} <= set(label for label, _ in r.diffs)


def test_a_log_of_the_previous_firmware_is_refused_with_what_to_do(tmp_path, capsys):
    # what tipbot_fw 0.1.0 wrote: the detector's columns, gains of schema 1, no estimator field
    header, rows = logfile.read_log(simulate(tmp_path / "det.log", sysfs=False,
                                             config_overrides={"estimator": "detector"}))
    header["gains"] = dict(header["gains"], schema_version=1)
    header["versions"] = dict(header["versions"], tipbot_fw="0.1.0")
    del header["estimator"]
    path = write_raw(tmp_path / "old.log", header, rows)
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2 and out == ""
    assert "a log of tipbot_fw 0.1.0, recorded with gains of schema 1" in err
    assert "replay it with the tipbot version that wrote it" in err


def test_a_log_beyond_log_max_rows_keeps_its_start_and_end_replays_exactly_and_says_what_is_missing(tmp_path, capsys):
    runs = []
    path = simulate(tmp_path / "long.log", sysfs=False, config_overrides={"log_max_rows": 200, "log_head_rows": 50},
                    result=runs)
    header, rows = logfile.read_log(path)
    # the simulator's view of the firmware's estimates: tick k at sample k, nothing where not kept
    xhat = runs[0].xhat
    assert np.isnan(xhat[50:150]).all() and np.isfinite(xhat[:50]).all() and np.isfinite(xhat[150:300]).all()
    # 300 ticks: the first 50, then a ring of 3 chunks of 50 holding the last ones, 150..299
    assert header["ticks"] == 300 and len(rows) == 200 and header["rows_not_recorded"] == 100
    assert header["segments"] == [[0, 50], [150, 150]] and header["not_kept"] == [[50, 149]]
    r = replay.replay_log(path)
    assert r.exact, r.diffs
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 0 and "replays exactly" in out
    assert "ticks 50..149 not kept (0.5 s;" in out and "re-seeded from its logged row" in out
    # the export holds the same rows, and its header the gap
    from hostsim.logs import export
    csv_path, header_path = export.export_csv(path, str(tmp_path / "long.csv"))
    assert len(open(csv_path).read().splitlines()) == 1 + 200
    assert json.load(open(header_path))["not_kept"] == [[50, 149]]


def test_the_firmware_log_from_the_in_memory_devices_replays_exactly(tmp_path):
    r = replay.replay_log(simulate(tmp_path / "mem.log", sysfs=False))
    assert r.exact, r.diffs


def test_a_replay_that_differs_from_the_log_is_reported(sim_log, tmp_path, capsys):
    header, rows = logfile.read_log(sim_log)
    rows = rows.copy()
    k = len(rows) // 2
    rows[k, col(header, "xi_th1")] += 2 ** -20      # as if the robot had computed otherwise
    bad = write_raw(tmp_path / "tampered.log", header, rows)
    code, out, err = run_main(capsys, bad, "--no-plots")
    assert code == 1
    assert "DIFFERS from the log: filter state xi by up to 9.54e-07" in out
    assert "first at row %d" % k in out


# ------------------------------------------------------------------ other gains
@pytest.mark.slow
def test_other_gains_show_what_they_would_have_commanded(sim_log, tmp_path, capsys):
    code, out, err = run_main(capsys, sim_log, "--gains", PAPER_GAINS, "--out", tmp_path)
    assert code == 0, err
    assert "replays exactly" in out            # the logged gains are still found (gains/)
    assert "what-if with %s" % PAPER_GAINS in out
    r = replay.replay_log(sim_log, gains_path=PAPER_GAINS)
    assert max(m for m, _ in r.other_u_diff.values()) > 0.1
    # the raw readings are the log's; what the controller makes of them is not
    raw = [col(r.header, n) for n in ("enc_r", "enc_l", "enc_2", "enc_3", "gyro_angle", "gyro_rate")]
    assert np.array_equal(r.other[:, raw], r.rows[:, raw])
    assert not np.allclose(r.other[:, col(r.header, "duty_r")], r.rows[:, col(r.header, "duty_r")])


def test_the_logged_gains_are_found_by_their_hash_next_to_the_log(sim_log, tmp_path):
    d = tmp_path / "logs" / "ev3dev.local"
    d.mkdir(parents=True)
    log = shutil.copy(sim_log, str(d / "tipbot-copy.log"))
    header, _ = logfile.read_log(log)
    fetched = d / ("gains-%s.json" % header["gains"]["sha256"][:16])     # as `make logs` names it
    shutil.copy(PHYSICAL_GAINS, str(fetched))
    assert replay.replay_log(log).logged_gains_path == str(fetched)


def test_unknown_logged_gains_are_asked_for(sim_log, tmp_path, capsys):
    header, rows = logfile.read_log(sim_log)
    header["gains"] = dict(header["gains"], sha256="f" * 64, path="/home/robot/tipbot/gains.json")
    log = write_raw(tmp_path / "other.log", header, rows)
    code, out, err = run_main(capsys, log, "--no-plots")
    assert code == 2
    assert "recorded with gains sha256 ffffffffffffffff" in err and "pass it with --gains FILE" in err
    # other gains still show what they would have commanded
    code, out, err = run_main(capsys, log, "--no-plots", "--gains", PAPER_GAINS)
    assert code == 0, err
    assert "exact replay skipped" in out and "what-if with" in out


def test_other_gains_with_another_period_are_refused(sim_log, capsys):
    other = os.path.join(os.path.dirname(PHYSICAL_GAINS), "physical-ts0.010.json")
    code, out, err = run_main(capsys, sim_log, "--no-plots", "--gains", other)
    assert code == 2
    assert "the log was sampled every 0.005 s" in err


# ------------------------------------------------------------------ bad logs
def _bytes(path):
    with open(path, "rb") as f:
        return f.read()


def records(data):
    """[(tag, start, end)] of the records of a format-2 log (logcontainer)."""
    out, pos = [], len(logfile.MAGIC) + 4
    while pos < len(data):
        tag, n, _ = struct.unpack_from("<4sII", data, pos)
        out.append((tag, pos, pos + 12 + n + 4))
        pos += 12 + n + 4
    return out


@pytest.mark.parametrize("keep", ["nothing", "part of the preamble", "part of the header"])
def test_a_log_cut_before_its_header_is_refused(sim_log, tmp_path, capsys, keep):
    data = _bytes(sim_log)
    head = records(data)[0]
    n = {"nothing": 0, "part of the preamble": 10, "part of the header": (head[1] + head[2]) // 2}[keep]
    path = tmp_path / "cut.log"
    path.write_bytes(data[:n])
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2 and out == ""
    assert err.startswith("replay: error: %s: truncated" % path), err


@pytest.mark.parametrize("keep", ["part of the rows", "all but the end record", "zeros instead of the rows"])
def test_a_log_cut_short_replays_its_intact_rows_and_says_so(sim_log, tmp_path, capsys, keep):
    data = _bytes(sim_log)
    recs = records(data)
    rows_recs = [r for r in recs if r[0] == b"ROWS"]
    third = rows_recs[len(rows_recs) // 3]
    if keep == "part of the rows":
        cut = data[:(third[1] + third[2]) // 2]
    elif keep == "all but the end record":
        cut = data[:recs[-1][1]] + data[recs[-1][1]:recs[-1][2] - 7]
    else:       # the preallocated space a power cut leaves: zeros where records were to come
        cut = data[:third[1]] + bytes(len(data) - third[1])
    path = tmp_path / "cut.log"
    path.write_bytes(cut)
    header, rows = logfile.read_log(str(path))
    intact = sum(1 for r in rows_recs if r[2] <= len(cut) and (keep != "zeros instead of the rows" or r[2] <= third[1]))
    assert header["incomplete"] and len(rows) == sum(
        struct.unpack_from("<QI", data, r[1] + 12)[1] for r in rows_recs[:intact])
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 0, err
    assert "replays exactly" in out and "the log is incomplete: " in out


@pytest.mark.parametrize("where", ["HEAD", "ROWS"])
def test_a_corrupted_log_is_refused(sim_log, tmp_path, capsys, where):
    data = bytearray(_bytes(sim_log))
    rec = [r for r in records(bytes(data)) if r[0] == where.encode()][0]
    data[rec[1] + 12 + 30] ^= 0x10
    path = tmp_path / "bad.log"
    path.write_bytes(bytes(data))
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2
    assert "corrupted: CRC32 of the %s record" % where in err, err


def test_a_file_that_is_not_a_log_is_refused(tmp_path, capsys):
    path = tmp_path / "notes.log"
    path.write_text("time,u\n0,1\n")
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2 and "not a tipbot log" in err
    code, out, err = run_main(capsys, tmp_path / "absent.log", "--no-plots")
    assert code == 2 and "no such log file" in err


def test_a_log_of_another_format_version_is_refused(sim_log, tmp_path, capsys):
    header, rows = logfile.read_log(sim_log)
    path = write_raw(tmp_path / "v3.log", header, rows, version=logfile.FORMAT_VERSION + 1)
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2
    assert "log format version %d is not supported" % (logfile.FORMAT_VERSION + 1) in err


def test_an_identify_log_is_refused_with_where_to_take_it(tmp_path, capsys):
    from tipbot_fw import identify
    path = str(tmp_path / "motor.log")
    identify.write_identify_log(path, {"port": "outA"}, [0.0] * (3 * identify.N_COLUMNS))
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2
    assert "a log of kind 'identify', not a balance run" in err and "python -m hostsim identify" in err


def test_a_log_with_columns_of_another_firmware_version_is_refused(sim_log, tmp_path, capsys):
    header, rows = logfile.read_log(sim_log)
    header["versions"] = dict(header["versions"], tipbot_fw="9.0.0")
    columns = header["columns"] + [{"name": "motor_current_r", "unit": "A"}]
    path = write_raw(tmp_path / "newer.log", header, np.hstack([rows, np.zeros((len(rows), 1))]),
                     columns=columns)
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2
    assert "incompatible log: written by tipbot_fw 9.0.0" in err and "unknown: motor_current_r" in err


def test_a_log_whose_header_lacks_what_a_replay_needs_is_refused(sim_log, tmp_path, capsys):
    header, rows = logfile.read_log(sim_log)
    del header["calibration"]
    path = write_raw(tmp_path / "old.log", header, rows)
    code, out, err = run_main(capsys, path, "--no-plots")
    assert code == 2
    assert "incompatible log: its header lacks calibration" in err


def test_the_hostsim_command_line_dispatches_replay(sim_log, capsys):
    from hostsim.__main__ import main
    assert main(["replay", sim_log, "--no-plots"]) == 0
    assert "replays exactly" in capsys.readouterr().out
