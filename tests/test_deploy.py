"""Deployment to a brick over ssh: `make deploy`, `make run`, `make logs`, then the host replay.

The "brick" is this machine: a throwaway sshd on 127.0.0.1 (own host and user keys, config and
authorized_keys in a temporary directory) whose sessions see a `python3` that is this test's
interpreter: tools/sim-brick's Brick, the one `make sim-brick` starts. The firmware runs there through the deployed launcher, in its own process, against
a fake EV3 tree that `python -m hostsim fake-robot` drives in real time from the simulated robot.
tools/deploy's planning is also tested without ssh.
"""
import csv
import importlib.machinery
import importlib.util
import glob
import hashlib
import json
import os
import re
import shutil
import signal
import socket
import stat
import subprocess
import sys
import time

import pytest
from conftest import PAPER_GAINS, PHYSICAL_GAINS, REPO

pytestmark = pytest.mark.slow   # real processes or long studies: not in make test-fast

SHEBANG = b"#!/usr/bin/env python3\n"


def load_tool(name, module):
    loader = importlib.machinery.SourceFileLoader(module, os.path.join(REPO, "tools", name))
    spec = importlib.util.spec_from_loader(loader.name, loader)
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


deploy_tool = load_tool("deploy", "tipbot_deploy_tool")
sim_brick = load_tool("sim-brick", "tipbot_sim_brick_tool")     # the loopback brick of `make sim-brick`


# ------------------------------------------------------------------ staging and planning (no ssh)
def test_stage_holds_what_the_brick_needs_with_launcher_mode_shebang_and_lf(tmp_path):
    files = deploy_tool.stage_files("physical", None)
    names = set(files)
    assert {"tipbot", "install.sh", "tipbot.service", "gains.json", "tipbot_fw/__main__.py",
            "tipbot_fw/default_config.json", deploy_tool.MANIFEST} <= names
    assert "config.json" not in names
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    assert not [n for n in names if n.startswith(("hostsim", "tests", "tools", "params"))]
    data, mode = files["tipbot"]
    assert data.startswith(SHEBANG) and b"\r" not in data and mode & stat.S_IXUSR
    assert files["install.sh"][1] & stat.S_IXUSR
    with open(PHYSICAL_GAINS, "rb") as f:
        assert files["gains.json"][0] == f.read()
    # the manifest depends on the content only: staging again gives the same bytes
    assert deploy_tool.stage_files("physical", None)[deploy_tool.MANIFEST] == files[deploy_tool.MANIFEST]
    manifest = deploy_tool.parse_manifest(files[deploy_tool.MANIFEST][0].decode())
    assert manifest["tipbot"] == (hashlib.sha256(data).hexdigest(), 0o755)
    assert set(manifest) == names - {deploy_tool.MANIFEST}
    deploy_tool.write_stage(files, str(tmp_path / "stage"))
    st = os.stat(str(tmp_path / "stage" / "tipbot"))
    assert stat.S_IMODE(st.st_mode) == 0o755


def test_stage_gives_the_brick_lf_scripts_even_from_a_crlf_checkout(tmp_path, capsys):
    repo = tmp_path / "checkout"
    shutil.copytree(os.path.join(REPO, "tipbot_fw"), str(repo / "tipbot_fw"))
    shutil.copytree(os.path.join(REPO, "gains"), str(repo / "gains"))
    (repo / "ev3").mkdir()
    for name in ("tipbot", "install.sh", "tipbot.service"):
        with open(os.path.join(REPO, "ev3", name), "rb") as f:
            (repo / "ev3" / name).write_bytes(f.read().replace(b"\n", b"\r\n"))
    files = deploy_tool.stage_files("physical", None, repo=str(repo))
    assert "CR line endings" in capsys.readouterr().out
    for name in ("tipbot", "install.sh", "tipbot.service"):
        assert b"\r" not in files[name][0]
    assert files["tipbot"][0].startswith(SHEBANG)


def test_stage_refuses_what_the_firmware_would_refuse(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"limits": {"th1_rad": -1}}')
    with pytest.raises(deploy_tool.DeployError, match="limits.th1_rad"):
        deploy_tool.stage_files("physical", str(bad))
    with pytest.raises(deploy_tool.DeployError, match="no gains/nonesuch.json"):
        deploy_tool.stage_files("nonesuch", None)


def test_plan_sends_only_changes_chmods_modes_and_removes_what_was_deployed_before():
    files = {"a.py": (b"a", 0o644), "tipbot": (b"#!x", 0o755), "new.json": (b"n", 0o644)}
    sha = lambda b: hashlib.sha256(b).hexdigest()  # noqa: E731
    actual = {"a.py": (sha(b"a"), 0o644), "tipbot": (sha(b"#!x"), 0o644),
              "config.json": (sha(b"c"), 0o644), "mine.txt": (sha(b"m"), 0o644)}
    actual["gone.py"] = (sha(b"g"), 0o644)
    previous = {"a.py": (sha(b"a"), 0o644), "config.json": (sha(b"c"), 0o644), "gone.py": (sha(b"g"), 0o644)}
    send, chmod, remove = deploy_tool.plan(files, previous, actual)
    assert send == ["new.json"]
    assert chmod == {"tipbot": 0o755}
    assert remove == ["gone.py"]        # no longer deployed; the owner's config.json and mine.txt stay
    assert deploy_tool.plan(files, previous, actual, remove_config=True)[2] == ["config.json", "gone.py"]
    assert deploy_tool.plan(files, {}, actual, remove_config=True)[2] == ["config.json"]


def test_make_run_explains_each_exit_status_in_full():
    codes = deploy_tool.exit_codes()
    meanings = codes.MEANINGS
    assert sorted(meanings) == [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 130, 143]
    assert sorted(codes.WITH_LOG) == [0, 1, 3, 4, 5, 6, 7, 8, 9, 130, 143]     # every exit of a run but 2
    assert meanings[4].endswith("or (identify) the owner did not confirm that the motor is free to turn")
    assert meanings[3].endswith("(run) a log of the header only, naming them")


def test_remote_dir_is_under_home_unless_absolute():
    assert deploy_tool.remote_dir_expr("tipbot") == '"$HOME"/tipbot'
    assert deploy_tool.remote_dir_expr("~/robots/tipbot") == '"$HOME"/robots/tipbot'
    assert deploy_tool.remote_dir_expr("/opt/tip bot") == "'/opt/tip bot'"


# ------------------------------------------------------------------ the loopback brick
def _find_or_install_sshd():
    """Path of sshd, installing openssh-server (apt-get, as root) if it is missing; else None."""
    found = sim_brick.find_sshd()
    if found:
        return found
    if os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        try:
            subprocess.run(["apt-get", "update", "-qq"], env=env, timeout=300, check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            subprocess.run(["apt-get", "install", "-y", "-qq", "--no-install-recommends",
                            "openssh-server", "openssh-client"], env=env, timeout=600, check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except (subprocess.SubprocessError, OSError):
            return None
        return sim_brick.find_sshd()
    return None


class Brick(sim_brick.Brick):
    """The loopback brick as `testbrick`, with `make TARGET` run against it."""

    def __init__(self, root, sshd):
        sim_brick.Brick.__init__(self, root, sshd, python=sys.executable, alias="testbrick")

    def make(self, target, *args, timeout=120, repo=REPO):
        """Run `make TARGET HOST=testbrick ...` in the repo; -> CompletedProcess (text, merged output)."""
        cmd = ["make", "--no-print-directory", "-C", repo, target] + self.make_settings() + [
            "REMOTE_DIR=%s" % self.install_dir, "STAGE=%s" % os.path.join(self.root, "stage")] + list(args)
        return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                              universal_newlines=True, timeout=timeout)


@pytest.fixture(scope="module")
def brick(tmp_path_factory):
    sshd = _find_or_install_sshd()
    if sshd is None:
        pytest.skip("no sshd, and openssh-server could not be installed (needs root and apt-get; "
                    ".ci/run installs it)")
    if shutil.which("make") is None:
        pytest.skip("no make")
    b = Brick(str(tmp_path_factory.mktemp("brick")), sshd)
    yield b
    b.close()


# ------------------------------------------------------------------ deploy
def test_deploy_copies_only_changes_and_installs_a_launcher_brickman_can_start(brick, tmp_path):
    p = brick.make("deploy")
    assert p.returncode == 0, p.stdout
    assert "python-ev3dev2 2.1.0: ok" in p.stdout and "ready" in p.stdout
    first = re.search(r"^deploy: (\d+) files changed", p.stdout, re.M)
    assert first and int(first.group(1)) >= 20, p.stdout   # the package, launcher, gains, ...

    launcher = os.path.join(brick.install_dir, "tipbot")
    with open(launcher, "rb") as f:
        data = f.read()
    assert data.startswith(SHEBANG) and b"\r" not in data
    assert os.stat(launcher).st_mode & stat.S_IXUSR
    for rel in ("install.sh", "gains.json", "tipbot_fw/cores/core.py", "tipbot_fw/default_config.json"):
        assert os.path.isfile(os.path.join(brick.install_dir, rel)), rel
    assert os.path.isdir(os.path.join(brick.install_dir, "logs"))

    p = brick.make("deploy")
    assert p.returncode == 0, p.stdout
    assert "deploy: 0 files changed\n" in p.stdout

    # a config is one new file; a changed brick-side file is repaired; a deploy without CONFIG=
    # keeps the owner's config on the brick; only REMOVE_CONFIG=1 removes it
    config = tmp_path / "robot.json"
    config.write_text('{"realtime_priority": 0}\n')
    os.chmod(launcher, 0o644)
    p = brick.make("deploy", "CONFIG=%s" % config)
    assert p.returncode == 0, p.stdout
    assert "deploy: 2 files changed (config.json, tipbot;" in p.stdout
    assert os.stat(launcher).st_mode & stat.S_IXUSR
    on_brick = os.path.join(brick.install_dir, "config.json")
    p = brick.make("deploy")
    assert p.returncode == 0 and "deploy: 0 files changed\n" in p.stdout, p.stdout
    assert "the brick's own config.json kept (REMOVE_CONFIG=1 removes it)" in p.stdout
    with open(on_brick) as f:
        assert f.read() == '{"realtime_priority": 0}\n'
    p = brick.make("deploy", "REMOVE_CONFIG=1")
    assert "deploy: 0 files changed, 1 removed (config.json)" in p.stdout, p.stdout
    assert not os.path.exists(on_brick)

    p = brick.make("deploy", "DEPLOY_VARIANT=paper")
    assert "deploy: 1 file changed (gains.json;" in p.stdout, p.stdout
    with open(PAPER_GAINS, "rb") as f, \
            open(os.path.join(brick.install_dir, "gains.json"), "rb") as g:
        assert f.read() == g.read()


def test_deploy_refuses_gains_that_do_not_hold_their_plants_unless_forced(brick, tmp_path):
    checkout = tmp_path / "checkout"
    for d in ("tipbot_fw", "ev3", "gains", "tools"):
        shutil.copytree(os.path.join(REPO, d), str(checkout / d), ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(os.path.join(REPO, "Makefile"), str(checkout / "Makefile"))
    # a design whose file records that its loop does not hold every plant of its uncertainty set
    # (what hostsim gains writes when no weight on its ladder makes it robust: docs/gains.md)
    with open(PHYSICAL_GAINS) as f:
        doc = json.load(f)
    doc["robust_to_models"] = dict(doc["robust_to_models"], stabilized=False, worst_spectral_radius=1.0021)
    with open(str(checkout / "gains" / "physical-fragile.json"), "w") as f:
        json.dump(doc, f)
    where = "REMOTE_DIR=%s" % (tmp_path / "tipbot")
    p = brick.make("deploy", "DEPLOY_VARIANT=physical-fragile", where, repo=str(checkout))
    assert p.returncode != 0
    refusal = [line for line in p.stdout.splitlines() if line.startswith("deploy: ")]
    assert len(refusal) == 1, p.stdout
    assert refusal[0].startswith("deploy: not deployed: gains/physical-fragile.json does not hold every plant it was "
                                 "designed for (the paper/physical model(s) with their uncertainty: "
                                 "robust_to_models.stabilized is false, worst spectral radius 1.0021, least damping ")
    assert refusal[0].endswith("deploy it anyway with FORCE=1 (tools/deploy --force)")
    assert not os.path.exists(str(tmp_path / "tipbot"))                   # nothing reached the brick
    p = brick.make("deploy", "DEPLOY_VARIANT=physical-fragile", "FORCE=1", where, repo=str(checkout))
    assert p.returncode == 0, p.stdout
    with open(str(checkout / "gains" / "physical-fragile.json"), "rb") as f, \
            open(str(tmp_path / "tipbot" / "gains.json"), "rb") as g:
        assert f.read() == g.read()
    # the committed 10 ms fallback holds its plants: it deploys without FORCE
    p = brick.make("deploy", "DEPLOY_VARIANT=physical-ts0.010", where, repo=str(checkout))
    assert p.returncode == 0, p.stdout


def test_deploy_says_what_to_install_when_numpy_is_missing(brick, tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "numpy.py").write_text("raise ImportError('No module named numpy')\n")
    (site / "ev3dev2.py").write_text("__version__ = '2.1.0'\n")
    # -S: no site-packages, so this python3 has only the stand-ins above
    brick.use_python(sys.executable + " -S", "PYTHONPATH=%s\nexport PYTHONPATH\n" % site)
    try:
        p = brick.make("deploy")
    finally:
        brick.use_python(sys.executable)
    assert p.returncode != 0, p.stdout
    assert "install.sh: numpy: not installed" in p.stdout
    assert "sudo apt-get update && sudo apt-get install python3-numpy\n" in p.stdout
    assert "the brick is not ready" in p.stdout


def test_deploy_installs_the_systemd_unit_on_request(brick):
    calls = os.path.join(brick.root, "sudo-calls")
    unit = os.path.join(brick.root, "installed.service")
    sudo = os.path.join(brick.bin, "sudo")
    with open(sudo, "w") as f:   # records what would run as root; copies the unit it installs
        f.write('#!/bin/sh\necho "$*" >> %s\nif [ "$1" = install ]; then cp "$4" %s; fi\n' % (calls, unit))
    os.chmod(sudo, 0o755)
    try:
        p = brick.make("deploy", "SERVICE=1")
    finally:
        os.unlink(sudo)
    assert p.returncode == 0, p.stdout
    with open(calls) as f:
        done = f.read().splitlines()
    assert done[0].startswith("install -m 644 ") and done[0].endswith(" /etc/systemd/system/tipbot.service")
    assert done[1:] == ["systemctl daemon-reload", "systemctl enable tipbot.service"]
    with open(unit) as f:
        text = f.read()
    assert "ExecStart=%s/tipbot\n" % brick.install_dir in text
    assert "WorkingDirectory=%s\n" % brick.install_dir in text
    assert "User=%s\n" % brick.user in text


# ------------------------------------------------------------------ run, logs, replay
def test_run_on_the_brick_fetch_the_log_and_replay_it_exactly(brick, tmp_path):
    scenario = tmp_path / "loopback.json"
    # small gyro noise: the readings, estimates and inputs are not all zero
    scenario.write_text('{"name": "loopback", "sensors": {"gyro_noise_dps": 0.3}, "seed": 3}\n')
    config = str(tmp_path / "robot-config.json")
    sysfs = str(tmp_path / "sysfs")
    robot = sim_brick.FakeRobot(sysfs, str(scenario), config, duration_s=60)
    try:
        p = brick.make("deploy", "CONFIG=%s" % config)
        assert p.returncode == 0, p.stdout
        t0 = time.monotonic()
        # a course too (COURSE=: copied to the brick's courses/, driven from the let-go cue)
        course = tmp_path / "gentle course.json"
        course.write_text('[{"speed_mps": 0.05, "yaw_rate_dps": 10, "duration_s": 1}]\n')
        run = brick.make("run", "DURATION=3", "COURSE=%s" % course, "RUN_ARGS=--sysfs-root %s" % sysfs, timeout=90)
        took = time.monotonic() - t0
    finally:
        robot_out = robot.stop()
    out = run.stdout
    assert "tipbot: running %s/gains.json" % brick.install_dir in out, out + robot_out
    # 0: ran its 3 s; 6: stopped by its fall/joint limits (the controller's business, not this
    # test's): either way the firmware ran in real time against the fake EV3 and wrote its log
    status = [l for l in out.splitlines() if l.startswith("run: firmware exit status")]
    assert status and (status[0].startswith("run: firmware exit status 0:")
                       or status[0].startswith("run: firmware exit status 6:")), out + robot_out
    assert "run: log on the brick: %s/logs/tipbot-" % brick.install_dir in out
    assert took < 60

    dest = str(tmp_path / "logs")
    p = brick.make("logs", "LOGS_DIR=%s" % dest)
    assert p.returncode == 0, p.stdout
    assert "logs: 1 new log from testbrick" in p.stdout, p.stdout
    logs = glob.glob(os.path.join(dest, "tipbot-*.log"))
    assert len(logs) == 1
    with open(PHYSICAL_GAINS, "rb") as f:
        sha = hashlib.sha256(f.read()).hexdigest()
    assert os.path.isfile(os.path.join(dest, "gains-%s.json" % sha[:16]))
    p = brick.make("logs", "LOGS_DIR=%s" % dest)
    assert "logs: 0 new logs from testbrick" in p.stdout and "1 already here" in p.stdout, p.stdout

    from tipbot_fw.record import logfile
    header, rows = logfile.read_log(logs[0])
    assert len(rows) >= 10, header.get("stop_message")     # the control loop ran
    assert "released at" in robot_out, robot_out            # and the simulated robot moved
    assert os.path.realpath(header["gains"]["path"]) == os.path.realpath(os.path.join(brick.install_dir, "gains.json"))
    assert rows[:, [c["name"] for c in header["columns"]].index("gyro_rate")].std() > 0
    assert header["course"] == [{"speed_mps": 0.05, "yaw_rate_dps": pytest.approx(10.0), "duration_s": 1}]
    assert os.path.isfile(os.path.join(brick.install_dir, "courses", "gentle_course.json"))
    assert rows[:, [c["name"] for c in header["columns"]].index("ref_v_r")].max() > 0.04

    plots = str(tmp_path / "plots")
    rp = subprocess.run([sys.executable, "-m", "hostsim", "replay", logs[0], "--out", plots], cwd=REPO,
                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True, timeout=120)
    assert rp.returncode == 0, rp.stdout
    assert "replay with the logged gains (%s" % os.path.join(dest, "gains-") in rp.stdout
    assert "replays exactly" in rp.stdout
    assert sorted(os.listdir(plots)) == sorted(os.path.basename(logs[0])[:-4] + s
                                               for s in ("-estimates.png", "-inputs.png"))


def test_run_and_logs_before_any_deploy_say_to_deploy_first(brick, tmp_path):
    nowhere = "REMOTE_DIR=%s" % (tmp_path / "not-deployed")
    p = brick.make("run", nowhere, "DURATION=1")
    assert p.returncode != 0
    assert "no launcher %s/tipbot on the brick: deploy first" % (tmp_path / "not-deployed") in p.stdout, p.stdout
    p = brick.make("logs", nowhere, "LOGS_DIR=%s" % (tmp_path / "logs"))
    assert p.returncode != 0
    assert "nothing deployed there (make deploy HOST=testbrick)" in p.stdout, p.stdout


def test_the_real_time_fake_robot_holds_the_robot_until_the_firmware_drives_a_motor(tmp_path):
    from hostsim.sim.fake_robot import RealTimeRobot
    from hostsim.sim.scenario import parse_scenario
    from tipbot_fw.io.ev3dev import Ev3Devices

    sc = parse_scenario({"x0_si": [0, 0, 0.05, 0, 0, 0, 0, 0, 0, 0]}, "<test>")
    robot = RealTimeRobot(sc, str(tmp_path / "sys"), hold_s=10.0)
    try:
        assert robot.config["start_pose_rad"]["th1"] == 0.05
        devs = Ev3Devices(robot.config, sysfs_root=robot.fake.sysfs_root)   # run-direct, GYRO-G&A
        t = 0.0
        for _ in range(20):                       # held: time passes, the pose does not change
            t += 0.005
            robot.step(t)
        assert robot.t_release_s is None and robot.t_gyro_mode_s is not None
        assert robot.plant.x_si[2] == 0.05
        enc0, _ = devs.read_raw()
        devs.write_duties([40, 40, 0, 0])          # the firmware drives the wheels: let go
        for _ in range(40):
            t += 0.005
            robot.step(t)
        assert robot.t_release_s is not None
        enc1, _ = devs.read_raw()
        assert enc1[0] != enc0[0] and enc1[1] != enc0[1]   # the wheels turned
        devs.close()
    finally:
        robot.close()


def _free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_make_watch_records_the_telemetry_of_a_run_on_the_brick(brick, tmp_path):
    config, sysfs = str(tmp_path / "robot-config.json"), str(tmp_path / "sysfs")
    scenario = tmp_path / "loopback.json"
    scenario.write_text('{"name": "loopback", "sensors": {"gyro_noise_dps": 0.3}, "seed": 5}\n')
    robot = sim_brick.FakeRobot(sysfs, str(scenario), config, duration_s=60)
    record, port = str(tmp_path / "watched.csv"), _free_udp_port()
    try:
        assert brick.make("deploy", "CONFIG=%s" % config).returncode == 0
        p = brick.make("watch", "DURATION=2", "RUN_ARGS=--sysfs-root %s" % sysfs, "WATCH_PORT=%d" % port,
                       "RECORD=%s" % record, timeout=120)
    finally:
        robot_out = robot.stop()
    assert p.returncode == 0, p.stdout + robot_out
    # the brick sends back to the address its ssh session comes from
    assert "run: telemetry to 127.0.0.1:%d" % port in p.stdout and "run: firmware exit status 0" in p.stdout
    assert "watch: receiving telemetry from 127.0.0.1" in p.stdout
    # what the brick showed, as the fake robot saw it: hold, let go, balancing, done
    shown = [l.split(": ", 1)[1].strip() for l in robot_out.splitlines() if l.startswith("fake_robot: lights")]
    assert shown == ["lights: left amber, right amber", "lights: left amber, right green",
                     "lights: left green, right green", "lights: left green, right off"], robot_out
    dest = str(tmp_path / "logs")
    assert brick.make("logs", "LOGS_DIR=%s" % dest).returncode == 0
    from hostsim.logs import export
    log = sorted(glob.glob(os.path.join(dest, "tipbot-*.log")))[-1]
    # the log's physical columns as the export rebuilds them (with the gains make logs fetched)
    with open(export.export_csv(log, str(tmp_path / "log.csv"))[0]) as f:
        rows = list(csv.DictReader(f))
    with open(record) as f:
        got = list(csv.DictReader(f))
    # the default: one every 20 ticks, sent in a tick's slack (a tick left without it under the
    # machine's load sends at the next one that has it: the schedule then moves by a tick)
    ticks = [int(r["tick"]) for r in got]
    assert ticks[0] == 0 and all(b - a >= 20 for a, b in zip(ticks, ticks[1:])) and 17 <= len(got) <= 20, ticks
    for r in got:
        row = rows[int(r["tick"])]
        names = ("time_s", "xt_th1_rad", "xt_d_r_m", "u_l_V", "w_r_V", "battery_v", "duty_2_pct")
        assert [float(r[n]) for n in names] == [float(row[n]) for n in names]


def _processes_mentioning(text):
    found = []
    for pid in os.listdir("/proc"):
        try:
            with open("/proc/%s/cmdline" % pid, "rb") as f:
                if text.encode() in f.read():
                    found.append(int(pid))
        except (OSError, ValueError):
            continue
    return found


@pytest.mark.parametrize("how", ["stop", "ctrl-c"])
def test_make_sim_brick_prints_its_settings_and_stops_leaving_nothing_running(tmp_path, how):
    if _find_or_install_sshd() is None:
        pytest.skip("no sshd")
    d = str(tmp_path / "sim")
    tool = os.path.join(REPO, "tools", "sim-brick")
    p = subprocess.Popen([sys.executable, tool, "start", "--dir", d], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         universal_newlines=True, cwd=REPO)
    out = []
    try:
        for line in p.stdout:
            out.append(line)
            if line.startswith("Ctrl-C here"):
                break
        text = "".join(out)
        settings = re.search(r"^    HOST=(\S+) SSH='(ssh -F (\S+))'$", text, re.M)
        assert settings and settings.group(1) == "simbrick", text
        assert _processes_mentioning(d)          # sshd and the fake robot
        s = subprocess.run(settings.group(2).split() + ["simbrick", 'echo "$HOME $TIPBOT_SYSFS_ROOT"; python3 -c "import numpy"'],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True, timeout=30)
        assert s.returncode == 0 and s.stdout.split() == [os.path.join(d, "home"), os.path.join(d, "sysfs")], s.stdout
        if how == "stop":
            q = subprocess.run([sys.executable, tool, "stop", "--dir", d], stdout=subprocess.PIPE, universal_newlines=True,
                               timeout=60)
            assert q.returncode == 0 and "sim-brick: stopped the loopback brick" in q.stdout
        else:
            p.send_signal(signal.SIGINT)
        assert p.wait(60) == 0
    finally:
        if p.poll() is None:
            p.kill()
    assert "sim-brick: stopped (sshd and the fake robot)" in p.stdout.read()
    assert _processes_mentioning(d) == [] and not os.path.exists(os.path.join(d, "sim-brick.pid"))


@pytest.mark.parametrize("rc, ssh_cmd, expected, unexpected", [
    (0, "ssh -F /tmp/cfg", ["fetch the log with `make logs HOST=simbrick SSH='ssh -F /tmp/cfg'`"], ["give a DURATION"]),
    (0, "ssh", ["fetch the log with `make logs HOST=simbrick`"], ["SSH="]),
    (255, "ssh", ["lost the ssh connection", "make sim-brick (it prints the HOST= and SSH= to use)"], []),
])
def test_make_run_hints_work_as_printed(monkeypatch, capsys, rc, ssh_cmd, expected, unexpected):
    """The hints make run prints carry what they need (the SSH= of the loopback brick), say how to
    get a brick when there is none, and ask for no DURATION that was given."""
    class FakeSsh(object):
        def __init__(self, *args):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def run(self, script, capture=False, tty=False):
            return subprocess.CompletedProcess([], rc)
    monkeypatch.setattr(deploy_tool, "Ssh", FakeSsh)
    deploy_tool.run("simbrick", duration=10, ssh_cmd=ssh_cmd)
    out = capsys.readouterr().out
    for text in expected:
        assert text in out, out
    for text in unexpected:
        assert text not in out, out
