"""Motor identification (issue 6, the paper's Section 4): the firmware's identify command on the
fake EV3 with a simulated DC motor of known parameters -> identify log -> host fit -> parameters
file -> gains.

Lock-step (VirtualClock) and seeded: deterministic. One real-time run checks the command line
as a user runs it (firmware and simulated motor in separate processes).
"""
import io
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from hostsim.model import gains as host_gains
from hostsim.logs import identify as I
from hostsim.model.motors import TABLE2
from hostsim.sim.motor_sim import one_motor_fake, simulate_identify
from tipbot_fw import cli
from tipbot_fw.record import logfile
from tipbot_fw import identify as fw
from tipbot_fw.gains import load_gains
from conftest import PARAMS_FILE, REPO
from tipbot_fw.cores.detector_rows import DetectorRows


# (Table 2 motor, driver, role, battery volts at rest, seed)
LARGE = (1, "lego-ev3-l-motor", "right_wheel", 8.2, 1)
MEDIUM = (5, "lego-ev3-m-motor", "joint3", 7.6, 2)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """One simulated identify run of each motor: {role: (log path, params, header, bench)}."""
    d = tmp_path_factory.mktemp("identify")
    out = {}
    for motor, driver, role, battery_v, seed in (LARGE, MEDIUM):
        path = str(d / ("motor%d.log" % motor))
        code, header, bench = simulate_identify(TABLE2[motor], path, driver=driver, battery_v=battery_v, seed=seed,
                                                header_extra={"role": role})
        assert code == 0, header
        out[role] = (path, TABLE2[motor], header, bench)
    return out


# ------------------------------------------------------------------------------ the whole path
@pytest.mark.parametrize("role", ["right_wheel", "joint3"])
def test_identification_recovers_phi_and_alpha_within_5_percent(logs, role):
    path, p, header, bench = logs[role]
    # the log: the project's container, kind identify, every phase, motor stopped at the end
    h, rows = logfile.read_log(path)
    assert h["kind"] == "identify" and [c["name"] for c in h["columns"]] == list(fw.COLUMN_NAMES)
    assert set(rows[:, fw.COLUMN_NAMES.index("phase")]) == {0, 1, 2}
    assert h["stop_reason"] == "completed" and h["exit_code"] == 0
    assert not bench.state.running and bench.state.command == "stop" and bench.state.duty_sp == 0
    # a real EV3's measurement: whole-degree counts, a battery below 8.2 V that sags under load
    assert np.all(rows[:, 2] == np.round(rows[:, 2]))
    volts = np.array([v for _, _, _, v, mode in bench.trace if mode == "drive"])
    assert 7.3 < volts.min() < volts.max() < 8.2 and volts.max() - volts.min() > 0.05

    f = I.fit_log(path)
    s, rd = f["step"], f["rundown"]
    assert s["phi"] == pytest.approx(p.phi, rel=0.05)
    assert s["alpha"] == pytest.approx(p.alpha, rel=0.05)
    assert rd["tau_c"] == pytest.approx(p.tau_coast_s, rel=0.05)
    assert not rd["coulomb_dominated"]
    # Ke needs no assumption; with Km = Ke the derived parameters reproduce phi and alpha
    d = I.derive(s["phi"], s["alpha"], rd["tau_c"], p.ra_ohm)
    assert d["ke_v_s"] == pytest.approx(p.ke_v_s, rel=0.05)
    phi, alpha, tau = I.model_g(d)
    assert (phi, alpha, tau) == pytest.approx((s["phi"], s["alpha"], rd["tau_c"]), rel=1e-9)
    # with the true Jm given, Km and beta come out as Table 2's
    d = I.derive(s["phi"], s["alpha"], rd["tau_c"], p.ra_ohm, jm_kg_m2=p.jm_kg_m2)
    assert d["km_nm_a"] == pytest.approx(p.km_nm_a, rel=0.05)
    assert d["beta_nm_s"] == pytest.approx(p.beta_nm_s, rel=0.05)


def test_command_line_prints_table_2_plots_and_writes_params(logs, tmp_path, capsys):
    out_params = str(tmp_path / "identified.json")
    large, medium = logs["right_wheel"][0], logs["joint3"][0]
    code = I.main([large, medium, "--out", str(tmp_path / "plots"), "--write-params", out_params])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "right_wheel (1 log) beside Table 2 motor 1:" in text
    assert "joint3 (1 log) beside Table 2 motor 5:" in text
    assert "Km = Ke (SI, ideal motor)" in text
    assert os.path.getsize(tmp_path / "plots" / "identify.png") > 10000
    summary = json.load(open(tmp_path / "plots" / "identify.json"))
    assert summary["joint3"]["fits"][0]["phi"] == pytest.approx(TABLE2[5].phi, rel=0.05)

    doc = json.load(open(out_params))
    base = json.load(open(PARAMS_FILE))
    for key, entry in doc["parameters"].items():
        if key.startswith(("right_wheel_", "joint3_")):
            assert entry["source"].startswith("identified from motor"), entry
        else:
            assert entry == base["parameters"][key]
    assert doc["parameters"]["joint3_ke_v_s"]["value"] == pytest.approx(TABLE2[5].ke_v_s, rel=0.05)
    assert sorted(doc["identified"]) == ["joint3", "right_wheel"]
    assert doc["identified"]["right_wheel"]["alpha_s"] == pytest.approx(TABLE2[1].alpha, rel=0.05)

    # make gains with the identified parameters: both variants valid
    gains_dir = str(tmp_path / "gains")
    assert host_gains.main(["--params", out_params, "--out-dir", gains_dir]) == 0
    report = capsys.readouterr().out
    # other parameters than params/robot.json: files of their own, never gains/<variant>.json
    names = {v: host_gains.output_name(v, params_path=out_params) for v in ("paper", "physical")}
    assert sorted(os.listdir(gains_dir)) == sorted(names.values()) and "physical.json" not in names.values()
    for variant, name in names.items():
        g = load_gains(os.path.join(gains_dir, name))     # the firmware's validation
        assert g.closed_loop_spectral_radius < 1.0
        assert max(abs(e) for e in json.load(open(os.path.join(gains_dir, name)))["detector_eigenvalues"]) < 1.0
    phys = json.load(open(os.path.join(gains_dir, names["physical"])))
    assert phys["robust_to_models"]["stabilized"] is True, report
    assert phys["parameters"]["joint3_ke_v_s"] == pytest.approx(doc["parameters"]["joint3_ke_v_s"]["value"])


def test_roles_given_per_log_and_averaging(logs, tmp_path):
    large = logs["right_wheel"][0]
    # two runs of one motor are averaged; a role per log overrides the logs' own
    fits, groups = I.identify([large, large], roles=["left_wheel"], ra_ohm=8.0)
    assert len(groups) == 1 and groups[0].role == "left_wheel" and len(groups[0].fits) == 2
    assert groups[0].params["ra_ohm"] == 8.0 and groups[0].ra_source == "given (--ra-ohm 8)"
    with pytest.raises(I.IdentifyError, match="--role given 2 times for 1 logs"):
        I.identify([large], roles=["joint2", "joint3"])


# ------------------------------------------------------------------------------ clear errors
def _simulated(tmp_path, name, motor=1, **kw):
    path = str(tmp_path / (name + ".log"))
    code, header, bench = simulate_identify(TABLE2[motor], path, **kw)
    assert code == 0
    assert not bench.state.running
    return path


@pytest.mark.parametrize("name, kw, error, message", [
    ("short", dict(seconds=0.005), I.TooFewSamples, "too few samples: 2 rows while driven"),
    ("slow", dict(motor=5, period_s=0.02), I.TooFewSamples, "too few samples: the count changed only"),
    ("stalled", dict(blocked=True), I.MotorStalled, "the motor stalled: it turned 0 count"),
    # a loaded brick reading slowly: still "stalled", the more useful diagnosis
    ("stalled_slow", dict(blocked=True, seconds=0.3, period_s=0.05), I.MotorStalled,
     "the motor stalled: it turned 0 count"),
    ("unsteady", dict(seconds=0.15), I.NotSteady, "the motor never reached a steady speed"),
])
def test_unusable_logs_get_a_clear_error(tmp_path, capsys, name, kw, error, message):
    path = _simulated(tmp_path, name, **kw)
    with pytest.raises(error, match="^" + path + ": " + message):
        I.fit_log(path)
    assert I.main([path, "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("identify: error: %s: %s" % (path, message)) and len(err.splitlines()) == 1


def test_other_files_are_refused(tmp_path):
    balance = str(tmp_path / "run.log")
    logfile.write_log(balance, {"stop_reason": "completed"}, np.zeros((3, len(DetectorRows.columns))), DetectorRows.columns)
    with pytest.raises(I.NotAnIdentifyLog, match="not an identify log"):
        I.load_log(balance)
    good = _simulated(tmp_path, "good", seconds=0.5, rundown_seconds=0.5)
    data = bytearray(open(good, "rb").read())
    data[-100] ^= 0xff
    bad = str(tmp_path / "corrupt.log")
    open(bad, "wb").write(data)
    with pytest.raises(I.IdentifyError, match="corrupted: CRC32"):
        I.load_log(bad)
    # the balance-log replay refuses an identify log instead of misreading it
    from hostsim.logs import replay
    with pytest.raises(replay.ReplayError, match="kind 'identify', not a balance run"):
        replay.load_log(good)


def test_coulomb_dominated_run_down_is_reported(tmp_path):
    path = str(tmp_path / "coulomb.log")
    simulate_identify(TABLE2[1]._replace(coulomb_nm=0.01), path)
    f = I.fit_log(path)
    assert f["rundown"]["coulomb_dominated"]
    assert f["rundown"]["tau_with_coulomb"] == pytest.approx(TABLE2[1].tau_coast_s, rel=0.05)
    assert "Coulomb-dominated" in I.describe_fit(f)


# ------------------------------------------------------------------------------ the firmware side
def test_sigterm_while_driven_stops_the_motor_and_writes_the_log(tmp_path):
    path = str(tmp_path / "term.log")
    sent = []

    def hook(t_from, t_to, bench):
        if t_to > 1.0 and not sent:
            sent.append(t_to)
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    code, header, bench = simulate_identify(TABLE2[1], path, hook=hook)
    assert signal.getsignal(signal.SIGTERM) == before      # the handlers are put back
    assert code == 143 and header["stop_reason"] == "sigterm"
    assert not bench.state.running and bench.state.command == "stop"
    h, rows = logfile.read_log(path)
    # recorded until the signal (t = 0 is the drive command, after 0.3 s standing still)
    assert h["stop_reason"] == "sigterm" and rows[-1, 0] == pytest.approx(sent[0] - 0.3, abs=0.002)
    assert rows[-1, 3] == fw.PHASE_DRIVE
    with pytest.raises(I.IdentifyError, match="stopped early \\(sigterm"):
        I.load_log(path)


def test_read_failure_stops_the_motor(tmp_path):
    path = str(tmp_path / "fail.log")

    def hook(t_from, t_to, bench):
        if t_to > 0.5:
            bench.fake.io.fail(bench.fake.relpath("outA", "position"), "pread")

    code, header, bench = simulate_identify(TABLE2[5], path, driver="lego-ev3-m-motor", hook=hook)
    assert code == 5 and header["stop_reason"] == "device_failure"
    assert "reading position failed" in header["stop_message"]
    assert not bench.state.running and bench.state.command == "stop"


class _Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def fake_tree(tmp_path):
    fake = one_motor_fake("outB", "lego-ev3-m-motor", root_dir=str(tmp_path / "sys"), battery_v=7.9)
    yield fake
    fake.close()


QUICK = ["--seconds", "0.3", "--rundown-seconds", "0.05", "--still-seconds", "0.02"]


def test_cli_refuses_without_terminal_or_yes(fake_tree, monkeypatch, capsys):
    monkeypatch.setattr(fw, "run_identify", lambda *a, **k: pytest.fail("motor driven"))
    monkeypatch.setattr(sys, "stdin", io.StringIO("yes\n"))     # not a terminal
    assert cli.main(["identify", "--port", "outB", "--sysfs-root", fake_tree.sysfs_root]) == 4
    err = capsys.readouterr().err
    assert "refused: no terminal to confirm on and no --yes" in err and "lego-ev3-m-motor" in err
    assert "lift the wheel off the ground" in err
    monkeypatch.setattr(sys, "stdin", _Tty("no\n"))
    assert cli.main(["identify", "--port", "outB", "--sysfs-root", fake_tree.sysfs_root]) == 4
    assert "not confirmed ('no'): the motor was not driven" in capsys.readouterr().err
    assert not fake_tree.poll()["outB"].running


def test_cli_confirmed_on_a_terminal_runs_and_writes_the_log(fake_tree, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sys, "stdin", _Tty("yes\n"))
    log = str(tmp_path / "id.log")
    code = cli.main(["identify", "--port", "outB", "--duty", "-80", "--log", log,
                     "--sysfs-root", fake_tree.sysfs_root] + QUICK)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "Type yes to start:" in err and "STALLED?" in err     # nothing turns this fake motor
    h, rows = logfile.read_log(log)
    assert h["kind"] == "identify" and h["duty"] == -80 and h["driver"] == "lego-ev3-m-motor"
    assert h["port"] == "outB" and h["role"] == "left_wheel"   # what the default config has on outB
    assert h["battery_v_start"] == pytest.approx(7.9)
    st = fake_tree.poll()["outB"]
    assert not st.running and st.command == "stop" and st.duty_sp == 0
    with pytest.raises(I.MotorStalled):
        I.fit_log(log)


def test_cli_other_refusals(fake_tree, monkeypatch, tmp_path, capsys):
    root = fake_tree.sysfs_root
    assert cli.main(["identify", "--port", "outD", "--yes", "--sysfs-root", root]) == 3
    assert "port outD: no motor found (tacho motors on: outB)" in capsys.readouterr().err
    fake_tree.set_battery_v(6.0)
    assert cli.main(["identify", "--port", "outB", "--yes", "--sysfs-root", root]) == 4
    assert "below limits.min_battery_v" in capsys.readouterr().err
    fake_tree.set_battery_v(7.9)

    class Interrupted(_Tty):
        def readline(self):
            raise KeyboardInterrupt()
    monkeypatch.setattr(sys, "stdin", Interrupted())
    assert cli.main(["identify", "--port", "outB", "--sysfs-root", root]) == 130
    with pytest.raises(SystemExit) as e:
        cli.main(["identify", "--port", "outB", "--duty", "0"])
    assert e.value.code == 2


def test_identify_log_format_round_trip(tmp_path):
    path = str(tmp_path / "x.log")
    rows = [0.0, 0.0, 5.0, 1.0, 100.0, 8.0, 0.001, 0.0, 6.0, 1.0, 100.0, 8.0]
    fw.write_identify_log(path, {"duty": 100}, rows)
    h, r = logfile.read_log(path)
    assert h["kind"] == "identify" and h["format_version"] == logfile.FORMAT_VERSION
    assert r.tolist() == [rows[:6], rows[6:]]
    with pytest.raises(ValueError, match="not a whole number"):
        fw.write_identify_log(path, {}, rows[:5])


# ------------------------------------------------------------------------------ real time
@pytest.mark.slow
def test_real_time_command_line_against_the_simulated_motor(tmp_path):
    """As a user runs it: the simulated motor keeps a fake tree on the wall clock in one
    process, `python3 -m tipbot_fw identify` runs in another."""
    root = str(tmp_path / "ev3")
    env = dict(os.environ, PYTHONPATH=REPO)
    sim = subprocess.Popen([sys.executable, "-m", "hostsim", "motor-sim", "--realtime", "--root", root, "--motor", "5",
                            "--battery-v", "7.8", "--duration", "20"], cwd=REPO, env=env,
                           stdout=subprocess.PIPE, universal_newlines=True)
    try:
        assert sim.stdout.readline().startswith("motor_sim: ready")
        log = str(tmp_path / "rt.log")
        fwp = subprocess.run([sys.executable, "-m", "tipbot_fw", "identify", "--port", "outA", "--yes",
                              "--seconds", "0.6", "--rundown-seconds", "1.5", "--sysfs-root", root, "--log", log],
                             cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             universal_newlines=True, timeout=30)
        assert fwp.returncode == 0, fwp.stderr
    finally:
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=10)
    f = I.fit_log(log)
    # real time: the duty acts at the simulator's next poll (< 1 ms): looser than lock-step
    assert f["step"]["phi"] == pytest.approx(TABLE2[5].phi, rel=0.05)
    assert f["step"]["alpha"] == pytest.approx(TABLE2[5].alpha, rel=0.10)
    assert f["rundown"]["tau_c"] == pytest.approx(TABLE2[5].tau_coast_s, rel=0.10)
