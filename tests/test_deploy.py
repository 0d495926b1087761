"""Deployment to a brick over ssh: `make deploy`, `make run`, `make logs`, then the host replay.

The "brick" is this machine: a throwaway sshd on 127.0.0.1 (own host and user keys, config and
authorized_keys in a temporary directory) whose sessions see a `python3` that is this test's
interpreter. The firmware runs there through the deployed launcher, in its own process, against
a fake EV3 tree that `python -m hostsim fake-robot` drives in real time from the simulated robot.
tools/deploy's planning is also tested without ssh.
"""
import importlib.machinery
import importlib.util
import glob
import hashlib
import os
import pwd
import re
import shutil
import signal
import socket
import stat
import subprocess
import sys
import threading
import time

import pytest
from conftest import PAPER_GAINS, PHYSICAL_GAINS, REPO

SHEBANG = b"#!/usr/bin/env python3\n"


def load_deploy_tool():
    loader = importlib.machinery.SourceFileLoader("tipbot_deploy_tool", os.path.join(REPO, "tools", "deploy"))
    spec = importlib.util.spec_from_loader(loader.name, loader)
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


deploy_tool = load_deploy_tool()


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
    meanings = deploy_tool.exit_meanings()
    assert sorted(meanings) == [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 130, 143]
    assert meanings[4].endswith("or (identify) the owner did not confirm that the motor is free to turn")
    assert meanings[3].endswith("(run) a log of the header only, naming them")


def test_remote_dir_is_under_home_unless_absolute():
    assert deploy_tool.remote_dir_expr("tipbot") == '"$HOME"/tipbot'
    assert deploy_tool.remote_dir_expr("~/robots/tipbot") == '"$HOME"/robots/tipbot'
    assert deploy_tool.remote_dir_expr("/opt/tip bot") == "'/opt/tip bot'"


# ------------------------------------------------------------------ the loopback brick
def _find_or_install_sshd():
    """Path of sshd, installing openssh-server (apt-get, as root) if it is missing; else None."""
    for p in (shutil.which("sshd"), "/usr/sbin/sshd"):
        if p and os.access(p, os.X_OK) and shutil.which("ssh") and shutil.which("ssh-keygen"):
            return p
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
        if os.access("/usr/sbin/sshd", os.X_OK):
            return "/usr/sbin/sshd"
    return None


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _python_wrapper(path, python, extra=""):
    with open(path, "w") as f:
        f.write("#!/bin/sh\n%sexec %s \"$@\"\n" % (extra, python))
    os.chmod(path, 0o755)


class Brick(object):
    """A throwaway sshd on 127.0.0.1 and the make arguments that reach it."""

    def __init__(self, root, sshd):
        self.root = root
        self.bin = os.path.join(root, "bin")           # first on the sessions' PATH
        self.install_dir = os.path.join(root, "home", "tipbot")
        self.user = pwd.getpwuid(os.getuid()).pw_name
        os.makedirs(self.bin)
        for name in ("host_key", "user_key"):
            subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "tipbot-test",
                            "-f", os.path.join(root, name)], check=True)
        shutil.copy(os.path.join(root, "user_key.pub"), os.path.join(root, "authorized_keys"))
        self.use_python(sys.executable)
        # Every session runs its command with /bin/sh (as on the brick, where ssh commands meet
        # dash) with our bin/ first on PATH, whatever the account's shell start-up files do.
        force = os.path.join(root, "session")
        with open(force, "w") as f:
            f.write('#!/bin/sh\nPATH=%s:$PATH\nexport PATH\nexec /bin/sh -c "$SSH_ORIGINAL_COMMAND"\n' % self.bin)
        os.chmod(force, 0o755)
        if os.geteuid() == 0:
            os.makedirs("/run/sshd", exist_ok=True)     # sshd's privilege separation directory
        self.proc = None
        for _ in range(3):
            self.port = _free_port()
            if self._start(sshd, force):
                break
        else:
            raise RuntimeError("could not start sshd: " + self.sshd_log())
        self.ssh_config = os.path.join(root, "ssh_config")
        with open(os.path.join(root, "host_key.pub")) as f:
            host_key = f.read().split()
        with open(os.path.join(root, "known_hosts"), "w") as f:
            f.write("[127.0.0.1]:%d %s %s\n" % (self.port, host_key[0], host_key[1]))
        with open(self.ssh_config, "w") as f:
            f.write("Host testbrick\n  HostName 127.0.0.1\n  Port %d\n  User %s\n"
                    "  IdentityFile %s\n  IdentitiesOnly yes\n  UserKnownHostsFile %s\n"
                    "  StrictHostKeyChecking yes\n  BatchMode yes\n  LogLevel ERROR\n"
                    "  ConnectTimeout 10\n"
                    % (self.port, self.user, os.path.join(root, "user_key"), os.path.join(root, "known_hosts")))
        deadline = time.monotonic() + 15
        while True:
            p = subprocess.run(["ssh", "-F", self.ssh_config, "testbrick", "true"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=20)
            if p.returncode == 0:
                break
            if time.monotonic() > deadline:
                self.close()
                raise RuntimeError("ssh to the test sshd fails: %s\n%s" % (p.stdout, self.sshd_log()))
            time.sleep(0.2)

    def _start(self, sshd, force):
        cfg = os.path.join(self.root, "sshd_config")
        with open(cfg, "w") as f:
            f.write("\n".join([
                "Port %d" % self.port, "ListenAddress 127.0.0.1",
                "HostKey %s" % os.path.join(self.root, "host_key"),
                "PidFile %s" % os.path.join(self.root, "sshd.pid"),
                "AuthorizedKeysFile %s" % os.path.join(self.root, "authorized_keys"),
                "StrictModes no", "UsePAM no", "PermitRootLogin yes", "AllowUsers %s" % self.user,
                "PubkeyAuthentication yes", "PasswordAuthentication no",
                "KbdInteractiveAuthentication no", "ForceCommand %s" % force, "LogLevel VERBOSE", ""]))
        self.log_path = os.path.join(self.root, "sshd.log")
        self.log = open(self.log_path, "ab")
        self.proc = subprocess.Popen([sshd, "-D", "-e", "-f", cfg], stdout=self.log, stderr=self.log,
                                     stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                return False
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return True
            except OSError:
                time.sleep(0.05)
        self.proc.kill()
        return False

    def sshd_log(self):
        with open(self.log_path, "rb") as f:
            return f.read().decode("utf-8", "replace")[-3000:]

    def use_python(self, python, extra=""):
        """The brick's python3 from now on."""
        _python_wrapper(os.path.join(self.bin, "python3"), python, extra)

    def make(self, target, *args, timeout=120, repo=REPO):
        """Run `make TARGET HOST=testbrick ...` in the repo; -> CompletedProcess (text, merged output)."""
        cmd = ["make", "--no-print-directory", "-C", repo, target, "HOST=testbrick",
               "SSH=ssh -F %s" % self.ssh_config, "REMOTE_DIR=%s" % self.install_dir,
               "STAGE=%s" % os.path.join(self.root, "stage")] + list(args)
        return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                              universal_newlines=True, timeout=timeout)

    def close(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()


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
    for rel in ("install.sh", "gains.json", "tipbot_fw/core.py", "tipbot_fw/default_config.json"):
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


def test_deploy_refuses_gains_that_do_not_hold_the_other_model_unless_forced(brick, tmp_path):
    checkout = tmp_path / "checkout"
    for d in ("tipbot_fw", "ev3", "gains", "tools"):
        shutil.copytree(os.path.join(REPO, d), str(checkout / d), ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(os.path.join(REPO, "Makefile"), str(checkout / "Makefile"))
    # the gains for a 10 ms loop: their own file, which records that they cannot hold the paper model
    p = subprocess.run(["make", "--no-print-directory", "-C", REPO, "gains", "TS=0.010", "VARIANT=physical",
                        "GAINS_DIR=%s" % (checkout / "gains")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                       universal_newlines=True, timeout=300)
    assert p.returncode == 0, p.stdout
    where = "REMOTE_DIR=%s" % (tmp_path / "tipbot")
    p = brick.make("deploy", "DEPLOY_VARIANT=physical-ts0.010", where, repo=str(checkout))
    assert p.returncode != 0
    refusal = [line for line in p.stdout.splitlines() if line.startswith("deploy: ")]
    assert len(refusal) == 1, p.stdout
    assert refusal[0].startswith("deploy: not deployed: gains/physical-ts0.010.json does not stabilize the paper "
                                 "model it must also hold (robust_to_models.stabilized is false, worst spectral radius ")
    assert refusal[0].endswith("deploy it anyway with FORCE=1 (tools/deploy --force)")
    assert not os.path.exists(str(tmp_path / "tipbot"))                   # nothing reached the brick
    p = brick.make("deploy", "DEPLOY_VARIANT=physical-ts0.010", "FORCE=1", where, repo=str(checkout))
    assert p.returncode == 0, p.stdout
    with open(str(checkout / "gains" / "physical-ts0.010.json"), "rb") as f, \
            open(str(tmp_path / "tipbot" / "gains.json"), "rb") as g:
        assert f.read() == g.read()


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
class FakeRobot(object):
    """python -m hostsim fake-robot in its own process; ready once the tree exists."""

    def __init__(self, root, scenario, config, duration_s=60):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hostsim", "fake-robot", "--root", root, "--scenario", scenario,
             "--write-config", config, "--duration", str(duration_s)],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
        self.lines = []
        self.ready = threading.Event()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        if not self.ready.wait(60):
            self.stop()
            raise RuntimeError("fake robot not ready:\n" + "".join(self.lines))

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)
            if line.startswith("fake_robot: ready"):
                self.ready.set()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.reader.join(5)
        return "".join(self.lines)


def test_run_on_the_brick_fetch_the_log_and_replay_it_exactly(brick, tmp_path):
    scenario = tmp_path / "loopback.json"
    # small gyro noise: the readings, estimates and inputs are not all zero
    scenario.write_text('{"name": "loopback", "sensors": {"gyro_noise_dps": 0.3}, "seed": 3}\n')
    config = str(tmp_path / "robot-config.json")
    sysfs = str(tmp_path / "sysfs")
    robot = FakeRobot(sysfs, str(scenario), config)
    try:
        p = brick.make("deploy", "CONFIG=%s" % config)
        assert p.returncode == 0, p.stdout
        t0 = time.monotonic()
        run = brick.make("run", "DURATION=3", "RUN_ARGS=--sysfs-root %s" % sysfs, timeout=90)
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

    from tipbot_fw import logfile
    header, rows = logfile.read_log(logs[0])
    assert len(rows) >= 10, header.get("stop_message")     # the control loop ran
    assert "released at" in robot_out, robot_out            # and the simulated robot moved
    assert os.path.realpath(header["gains"]["path"]) == os.path.realpath(os.path.join(brick.install_dir, "gains.json"))
    assert rows[:, logfile.col("gyro_rate")].std() > 0

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
    from tipbot_fw.ev3io import Ev3Devices

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
