"""The files that go onto the brick besides the package: ev3/tipbot, ev3/install.sh, ev3/tipbot.service."""
import configparser
import os
import shutil
import stat
import subprocess
import sys
import textwrap

import pytest
from conftest import REPO

EV3 = os.path.join(REPO, "ev3")


def read_bytes(name):
    with open(os.path.join(EV3, name), "rb") as f:
        return f.read()


def test_brick_files_are_lf_and_executable():
    for name in ("tipbot", "install.sh", "tipbot.service"):
        raw = read_bytes(name)
        assert b"\r" not in raw, name + ": CR in file (brickman/sh need LF line endings)"
        raw.decode("ascii")
    assert read_bytes("tipbot").startswith(b"#!/usr/bin/env python3\n")
    assert read_bytes("install.sh").startswith(b"#!/bin/sh\n")
    for name in ("tipbot", "install.sh"):
        mode = os.stat(os.path.join(EV3, name)).st_mode
        assert mode & stat.S_IXUSR, name + ": no owner execute bit (chmod u+x)"


def make_install_dir(tmp_path, gains=True):
    d = tmp_path / "tipbot"
    (d / "tipbot_fw" / "guard").mkdir(parents=True)
    shutil.copy2(os.path.join(EV3, "tipbot"), str(d / "tipbot"))
    shutil.copy2(os.path.join(EV3, "install.sh"), str(d / "install.sh"))
    shutil.copy2(os.path.join(EV3, "tipbot.service"), str(d / "tipbot.service"))
    # the real supervisor (the launcher becomes it) and a stand-in firmware that reports how it
    # was started
    for name in ("supervisor.py", "vocabulary.py", "guard/__init__.py", "guard/heartbeat.py", "config.py", "fields.py",
                 "guard/safety.py", "guard/exit_codes.py",
                 "guard/realtime.py", "default_config.json"):
        shutil.copy2(os.path.join(REPO, "tipbot_fw", name), str(d / "tipbot_fw" / name))
    (d / "tipbot_fw" / "__init__.py").write_text("")
    (d / "tipbot_fw" / "__main__.py").write_text(textwrap.dedent("""\
        import os, sys
        print("argv=" + repr(sys.argv[1:]))
        print("cwd=" + os.getcwd())
        print("main=" + os.path.dirname(os.path.abspath(__file__)))
        print("supervised=%s" % ("TIPBOT_SUPERVISOR" in os.environ))
        sys.exit(3)
        """))
    if gains:
        (d / "gains.json").write_text("{}")
    return d


def test_launcher_runs_the_firmware_with_the_deployed_files(tmp_path):
    d = make_install_dir(tmp_path)
    env = dict(os.environ)
    env.pop("TIPBOT_GAINS", None)
    env.pop("TIPBOT_CONFIG", None)
    p = subprocess.run([sys.executable, str(d / "tipbot"), "--duration", "2"], cwd=str(tmp_path),
                       env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    assert p.returncode == 3, p.stderr
    assert "argv=['run', '--gains', '%s', '--duration', '2']" % (d / "gains.json") in p.stdout
    assert "cwd=%s" % (d / "logs") in p.stdout
    assert "main=%s" % (d / "tipbot_fw") in p.stdout
    assert "supervised=True" in p.stdout

    (d / "config.json").write_text("{}")
    p = subprocess.run([sys.executable, str(d / "tipbot")], env=env, stdout=subprocess.PIPE,
                       universal_newlines=True)
    assert "'--config', '%s'" % (d / "config.json") in p.stdout


def test_the_owners_files_named_relative_to_where_the_launcher_starts_are_found_from_logs(tmp_path):
    d = make_install_dir(tmp_path)
    (tmp_path / "mine.json").write_text("{}")
    p = subprocess.run([sys.executable, str(d / "tipbot"), "--config", "mine.json", "--gains=g.json",
                        "--course", "c.json", "--log", "run.log"], cwd=str(tmp_path),
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    assert "'--config', '%s'" % (tmp_path / "mine.json") in p.stdout, p.stdout + p.stderr
    assert "'--gains=%s'" % (tmp_path / "g.json") in p.stdout
    assert "'--course', '%s'" % (tmp_path / "c.json") in p.stdout
    assert "'--log', 'run.log'" in p.stdout         # a log lands in logs/


def test_launcher_without_gains_says_what_to_do(tmp_path):
    d = make_install_dir(tmp_path, gains=False)
    p = subprocess.run([sys.executable, str(d / "tipbot")], stdout=subprocess.PIPE,
                       stderr=subprocess.PIPE, universal_newlines=True)
    assert p.returncode != 0
    assert "no gains file" in p.stderr and "make deploy" in p.stderr


def fake_python(tmp_path, numpy=None, ev3dev2=None):
    """A python3 stand-in whose numpy/ev3dev2 are present (with a version) or missing."""
    site = tmp_path / "fake_site"
    site.mkdir()
    for mod, ver in (("numpy", numpy), ("ev3dev2", ev3dev2)):
        if ver:
            (site / (mod + ".py")).write_text("__version__ = %r\n" % ver)
        else:
            (site / (mod + ".py")).write_text("raise ImportError('no %s')\n" % mod)
    script = tmp_path / "python3"
    # -S: no site-packages, so only the stand-in modules above are importable
    script.write_text("#!/bin/sh\nPYTHONPATH=%s exec %s -S \"$@\"\n" % (site, sys.executable))
    script.chmod(0o755)
    return str(script)


def run_install(d, python):
    env = dict(os.environ, PYTHON=python)
    return subprocess.run(["sh", str(d / "install.sh")], env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, universal_newlines=True)


def test_install_sh_prints_what_to_install(tmp_path):
    d = make_install_dir(tmp_path)
    p = run_install(d, fake_python(tmp_path, numpy=None, ev3dev2=None))
    assert p.returncode == 1, p.stdout
    assert "sudo apt-get update && sudo apt-get install python3-numpy python3-ev3dev2" in p.stdout


def test_install_sh_refuses_old_numpy_and_accepts_the_brick(tmp_path):
    d = make_install_dir(tmp_path)
    p = run_install(d, fake_python(tmp_path, numpy="1.11.0", ev3dev2="2.1.0"))
    assert p.returncode == 1 and "sudo apt-get install python3-numpy\n" in p.stdout, p.stdout
    shutil.rmtree(str(tmp_path / "fake_site"))
    p = run_install(d, fake_python(tmp_path, numpy="1.12.1", ev3dev2="2.1.0"))
    assert p.returncode == 0, p.stdout
    assert "numpy 1.12.1: ok" in p.stdout and "python-ev3dev2 2.1.0: ok" in p.stdout
    assert "ready" in p.stdout


def test_service_unit_runs_the_launcher():
    cp = configparser.ConfigParser(interpolation=None, strict=True)
    cp.optionxform = str
    cp.read(os.path.join(EV3, "tipbot.service"))
    svc = cp["Service"]
    assert svc["ExecStart"] == svc["WorkingDirectory"] + "/tipbot"
    assert svc["KillSignal"] == "SIGINT"  # the firmware stops the motors on KeyboardInterrupt
    assert cp["Install"]["WantedBy"] == "multi-user.target"


def fake_sudo(tmp_path):
    """A `sudo` that runs its command as this user (install.sh's writes go to tmp_path)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "sudo").write_text('#!/bin/sh\nexec "$@"\n')
    (bin_dir / "sudo").chmod(0o755)
    return str(bin_dir)


def pam_rtprio(limits_file, user):
    """The rtprio a pam_limits session of ``user`` gets from the file install.sh wrote."""
    for line in limits_file.read_text().splitlines():
        fields = line.split()
        if len(fields) == 4 and not line.startswith("#") and fields[0] == user and fields[2] == "rtprio":
            return int(fields[3])
    return 0


def session_prefix(rtprio):
    """Commands that start a process as a login session with ``rtprio`` would: the rtprio limit
    set (prlimit: needs CAP_SYS_RESOURCE to raise it) and CAP_SYS_NICE dropped (setpriv), so that
    only the limit grants SCHED_FIFO. Where the limit cannot be raised, a session granted
    SCHED_FIFO some other way (as root here) stands in for rtprio > 0. None if neither works."""
    if not (shutil.which("setpriv") and shutil.which("prlimit")):
        return None
    faithful = ["prlimit", "--rtprio={0}:{0}".format(rtprio), "setpriv", "--bounding-set=-sys_nice",
                "--inh-caps=-sys_nice"]
    for prefix in ([faithful, []] if rtprio > 0 else [faithful]):
        probe = subprocess.run(prefix + [sys.executable, "-c", "import os; os.sched_setscheduler(0, os.SCHED_FIFO, "
                                         "os.sched_param(%d))" % max(1, rtprio)], stderr=subprocess.PIPE)
        if (probe.returncode == 0) == (rtprio > 0):
            return prefix
    return None


def launch_on_fake_ev3(tmp_path, prefix, name):
    """The launcher of a full install directory (the real firmware) on a fake EV3, 0.2 s."""
    from hostsim.world.fake_ev3 import FakeEV3
    d = tmp_path / name
    shutil.copytree(os.path.join(REPO, "tipbot_fw"), str(d / "tipbot_fw"),
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(os.path.join(EV3, "tipbot"), str(d / "tipbot"))
    shutil.copy2(os.path.join(REPO, "gains", "physical.json"), str(d / "gains.json"))
    (d / "config.json").write_text('{"gyro_calibration": {"settle_s": 0.02, "duration_s": 0.05}}')
    log = str(tmp_path / (name + ".log"))
    with FakeEV3(str(tmp_path / (name + "-sys")), battery_v=8.0) as fake:
        fake.set_readings((0, 0, 0, 0))
        p = subprocess.run(prefix + [sys.executable, str(d / "tipbot"), "--duration", "0.2", "--quiet",
                                     "--log", log, "--sysfs-root", fake.sysfs_root],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    return p, log


@pytest.mark.slow
def test_a_launcher_start_after_install_rtprio_runs_sched_fifo_and_one_without_says_so(tmp_path):
    """install.sh --rtprio writes the pam_limits line; a session that has it gets SCHED_FIFO from
    the launcher (start line and log header); one without it gets a one-line refusal and runs."""
    import getpass
    from tipbot_fw.record.logfile import read_log
    d = make_install_dir(tmp_path)
    limits_dir = tmp_path / "limits.d"
    limits_dir.mkdir()
    env = dict(os.environ, LIMITS_DIR=str(limits_dir), PATH=fake_sudo(tmp_path) + os.pathsep + os.environ["PATH"],
               PYTHON=fake_python(tmp_path, numpy="1.12.1", ev3dev2="2.1.0"))
    p = subprocess.run(["sh", str(d / "install.sh"), "--rtprio"], env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, universal_newlines=True)
    assert p.returncode == 0, p.stdout
    rtprio = pam_rtprio(limits_dir / "tipbot.conf", getpass.getuser())
    assert rtprio >= 51      # the loop's 50 and the supervisor's one above

    granted, refused = session_prefix(rtprio), session_prefix(0)
    if granted is None or refused is None:
        pytest.skip("this machine cannot start a session with a given rtprio and without CAP_SYS_NICE")
    p, log = launch_on_fake_ev3(tmp_path, granted, "installed")
    assert p.returncode == 0, p.stderr
    assert "tipbot: scheduling: SCHED_FIFO priority 50\n" in p.stderr
    assert read_log(log)[0]["loop"]["realtime"]["granted"] is True

    p, log = launch_on_fake_ev3(tmp_path, refused, "not-installed")
    assert p.returncode == 0, p.stderr
    lines = [l for l in p.stderr.splitlines() if "scheduling" in l or "priority" in l]
    assert len(lines) == 1 and lines[0].startswith("tipbot: scheduling: normal, SCHED_FIFO priority 50 refused ("), \
        p.stderr
    assert "./install.sh --rtprio" in lines[0]
    header = read_log(log)[0]
    assert header["loop"]["realtime"]["granted"] is False and header["loop"]["realtime"]["rtprio_limit"] == [0, 0]
