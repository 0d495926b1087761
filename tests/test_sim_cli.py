"""`python -m hostsim VERB`: every tool behind one command line with help on every option;
run and sim write their outputs, print the summary, and name a bad field."""
import argparse
import json
import os
import subprocess
import sys

import pytest

from conftest import REPO
from hostsim.__main__ import COMMANDS, main


class _Parsed(Exception):
    pass


@pytest.mark.parametrize("verb", sorted(COMMANDS))
def test_every_verb_has_help_on_every_option(verb, monkeypatch):
    seen = {}

    def parse_args(self, args=None, namespace=None):
        seen["prog"] = self.prog
        seen["bare"] = [a.option_strings or [a.dest] for a in self._actions if not a.help]
        raise _Parsed()

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    with pytest.raises(_Parsed):
        main([verb])
    assert seen["prog"] == "python -m hostsim " + verb
    assert seen["bare"] == [], "options without help: %s" % seen["bare"]


def test_the_verbs_run_as_a_module():
    p = subprocess.run([sys.executable, "-m", "hostsim", "bench-sim", "--help"], cwd=REPO,
                       capture_output=True, text=True)
    assert p.returncode == 0 and p.stdout.startswith("usage: python -m hostsim bench-sim")


@pytest.mark.slow
def test_run_writes_metrics_and_plots(tmp_path, capsys):
    out = tmp_path / "near"
    assert main(["run", "near_equilibrium", "--out", str(out), "--modes", "linear,nonlinear"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc["runs"]) == {"linear/optimal", "nonlinear/optimal"}
    assert doc["runs"]["linear/optimal"]["upright"]
    for name in doc["plots"].values():
        assert (out / name).stat().st_size > 1000
    text = capsys.readouterr().out
    assert "near_equilibrium" in text and "linear/optimal" in text


def test_run_fails_on_unmet_expectations(tmp_path, capsys):
    sc = tmp_path / "strict.json"
    sc.write_text(json.dumps({"duration_s": 1.0, "x0_si": [0, 0, 0.03, 0, 0, 0, 0, 0, 0, 0], "modes": ["linear"],
                              "expect": {"linear/optimal": {"max_abs_th1_rad": 0.001}}}))
    assert main(["run", str(sc), "--out", str(tmp_path / "o"), "--no-plots"]) == 1
    assert "EXPECTATION FAILED: linear/optimal max_abs_th1_rad" in capsys.readouterr().out


def test_run_names_the_bad_field(tmp_path, capsys):
    sc = tmp_path / "bad.json"
    sc.write_text(json.dumps({"duration_s": 1.0, "disturbances": [{"t_start_s": 1, "t_end_s": 2, "w_v": [1, 1]}]}))
    assert main(["run", str(sc), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and "disturbances[0].w_v" in err


def test_unknown_verb(capsys):
    assert main(["fly"]) == 2
    assert "unknown verb 'fly'" in capsys.readouterr().err
    assert main([]) == 0
    assert "montecarlo" in capsys.readouterr().out


@pytest.mark.slow
def test_sim_writes_the_report(tmp_path, capsys):
    out = tmp_path / "sim"
    sim_data = os.path.join(REPO, "docs", "data", "sim.json")
    with open(sim_data, "rb") as f:
        before = f.read()
    # (without the five payload and slope scenarios, which ran here unasked: 39 s, now 15 s)
    code = main(["sim", "--out", str(out), "--scenarios", "section7", "--no-robustness", "--device", "memory",
                 "--drive-scenarios", "drive_straight", "--load-scenarios"])
    assert code == 0
    with open(sim_data, "rb") as f:
        assert f.read() == before           # a partial study leaves the docs pages' figures alone
    report = (out / "report.md").read_text()
    assert "Where the paper's claims cannot hold" in report
    # the course: its tracking row (true path against the commanded one) and its plan view
    assert "| drive_straight | firmware/optimal | yes |" in report
    assert (out / "drive_straight" / "plan_view.png").exists()
    tracking = json.loads((out / "drive_straight" / "metrics.json").read_text())["runs"]["firmware/optimal"]["tracking"]
    assert 0.15 < tracking["max_speed_mps"] < 0.5 and tracking["final_position_error_m"] < 0.1
    assert "Section 7's initial state cannot be handled without saturation" in report
    for line in report.splitlines():
        if line.startswith("![") and "](" in line:
            assert os.path.exists(out / line.split("](")[1].rstrip(")"))
    text = capsys.readouterr().out
    assert "linear/optimal" in text and "report.md" in text


def test_pip_install_puts_the_verbs_on_path_as_tipbot_host(capsys):
    # setup.py's console script (make venv: pip install -e .) is the same command line
    import ast
    import importlib
    with open(os.path.join(REPO, "setup.py")) as f:
        tree = ast.parse(f.read())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    entry = ast.literal_eval(next(k.value for k in call.keywords if k.arg == "entry_points"))
    assert entry == {"console_scripts": ["tipbot-host = hostsim.__main__:main"]}
    module, func = entry["console_scripts"][0].split(" = ")[1].split(":")
    assert getattr(importlib.import_module(module), func)(["--help"]) == 0
    assert "watch" in capsys.readouterr().out


@pytest.mark.parametrize("argv, docs", [
    ([], True), (["--jobs", "1"], True), (["--no-docs"], False),
    (["--scenarios", "section7"], False), (["--no-robustness"], False), (["--mc-runs", "5"], False),
    (["--host-estimator", "kalman"], False), (["--drive-scenarios"], False)])
def test_only_the_whole_default_study_writes_the_docs_pages(tmp_path, monkeypatch, argv, docs):
    """make sim writes its generated blocks (hostsim.studies.sim_docs) only for the study they
    describe: where it writes the report and with how many workers do not matter."""
    from hostsim.studies import sim_study
    seen = {}
    monkeypatch.setattr(sim_study, "_study", lambda args, final: seen.setdefault("docs", args.docs) and 0)
    sim_study.main(argv + ["--out", str(tmp_path / "sim")])
    assert seen["docs"] is docs


def test_an_interrupted_sim_says_so_in_one_line_and_keeps_the_previous_report(tmp_path, capsys, monkeypatch):
    from hostsim.studies import runner
    out = tmp_path / "sim"
    out.mkdir()
    (out / "report.md").write_text("the previous report\n")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(runner, "run_and_write", interrupted)
    code = main(["sim", "--out", str(out), "--scenarios", "section7", "--no-robustness", "--device", "memory"])
    err = capsys.readouterr().err
    assert code == 130
    assert (out / "report.md").read_text() == "the previous report\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim"]       # no half-made report beside it
    assert "sim: interrupted: nothing new written; %s keeps the previous report" % out in err
    assert "Traceback" not in err


def test_long_jobs_say_how_far_they_are_while_they_run():
    import io
    import time as _time
    from hostsim.sim.parallel import Progress
    stream = io.StringIO()
    bar = Progress(4, "Monte Carlo", every_s=0.05, stream=stream)
    bar.update(1)
    _time.sleep(0.2)
    bar.close()
    lines = stream.getvalue().splitlines()
    assert lines[0] == "Monte Carlo: 4 to do"           # at once: the phase's start is no silence
    assert lines[1].startswith("Monte Carlo: 1/4 done, ") and "s left" in lines[1]
    assert "done in" not in lines[-1]                   # not all done: no closing line
    stream = io.StringIO()
    bar = Progress(2, "margins", every_s=60, stream=stream)
    bar.update(2)
    bar.close()
    assert stream.getvalue().splitlines() == ["margins: 2 to do", "margins: 2/2 done in 0 s"]


def test_tipbot_host_calls_itself_so(monkeypatch, capsys):
    # started as the console script, its usage lines and its tools' parsers say tipbot-host
    monkeypatch.setattr(sys, "argv", ["/venv/bin/tipbot-host", "export", "--help"])
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    out = capsys.readouterr().out
    assert out.startswith("usage: tipbot-host export")
    with pytest.raises(SystemExit):
        main(["export"])            # argparse's errors name the command too
    assert capsys.readouterr().err.splitlines()[-1].startswith("tipbot-host export: error:")
    assert main(["fly"]) == 2
    assert capsys.readouterr().err.startswith("tipbot-host: unknown verb 'fly'")
    monkeypatch.setattr(sys, "argv", ["-m"])
    assert main(["fly"]) == 2
    assert capsys.readouterr().err.startswith("python -m hostsim: unknown verb 'fly'")


def _study_stand_in(tmp_path):
    """A stand-in for the study behind make sim: says it started, then, on SIGINT, its one line."""
    fake = tmp_path / "python"
    fake.write_text("#!/usr/bin/env python3\nimport signal, sys, time\n"
                    "def stop(*a):\n    print('sim: interrupted: nothing new written', file=sys.stderr)\n"
                    "    sys.exit(130)\n"
                    "signal.signal(signal.SIGINT, stop)\nprint('started', flush=True)\ntime.sleep(30)\n")
    fake.chmod(0o755)
    return fake


def _ctrl_c_in_a_terminal(argv):
    """Run argv in the repository on a terminal (a pty), press Ctrl-C once it printed 'started';
    -> (its wait status, what the terminal showed besides 'started' and the echoed ^C: their
    order varies under load)."""
    import pty
    import select
    import time
    pid, fd = pty.fork()
    if pid == 0:
        os.chdir(REPO)
        os.execvp(argv[0], argv)
    out, sent, t0 = b"", False, time.monotonic()
    while time.monotonic() - t0 < 20:
        if select.select([fd], [], [], 0.1)[0]:
            try:
                data = os.read(fd, 4096)
            except OSError:
                break
            if not data:
                break
            out += data
        if not sent and b"started" in out:
            os.write(fd, b"\x03")
            sent = True
    _, status = os.waitpid(pid, 0)
    assert sent, out
    return status, out.decode(errors="replace").replace("^C", "").replace("started", "")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="a terminal: pty")
def test_ctrl_c_on_make_sim_is_one_line_and_status_130(tmp_path):
    """Ctrl-C on a terminal reaches make and the study: one line (not make's '*** [sim] Error
    130' after it), make ends on the signal; a SIGINT to the study alone is a failure."""
    import signal as sig
    import subprocess
    fake = _study_stand_in(tmp_path)
    status, text = _ctrl_c_in_a_terminal(["make", "-s", "sim", "VPY=%s" % fake])
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == sig.SIGINT     # the shell says 130
    assert [l for l in text.splitlines() if l.strip()] == ["sim: interrupted: nothing new written"], repr(text)
    p = subprocess.Popen(["make", "-s", "sim", "VPY=%s" % fake], cwd=REPO, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, universal_newlines=True, start_new_session=True)
    assert p.stdout.readline() == "started\n"
    child = next(int(c) for c in subprocess.check_output(["pgrep", "-P", str(p.pid)]).split())
    grandchildren = subprocess.run(["pgrep", "-P", str(child)], stdout=subprocess.PIPE).stdout.split()
    os.kill(int(grandchildren[0]) if grandchildren else child, sig.SIGINT)      # the study alone
    assert p.wait(timeout=20) == 2 and "Error 130" in p.stderr.read()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="a terminal: pty")
def test_ctrl_c_while_make_builds_the_venv_is_pips_one_line_and_no_stamp(tmp_path):
    """A fresh clone's first make sim builds the venv for about a minute: Ctrl-C there shows pip's
    one line, not make's error after it, and leaves no stamp (the next make builds it again).
    PYTHON is a stand-in: its pip install waits to be interrupted."""
    import signal as sig
    fake = tmp_path / "python3"
    fake.write_text("#!/usr/bin/env python3\nimport os, shutil, signal, sys, time\n"
                    "a = sys.argv[1:]\n"
                    "if a[:2] == ['-m', 'venv']:\n"
                    "    os.makedirs(os.path.join(a[2], 'bin'))\n"
                    "    shutil.copy(sys.argv[0], os.path.join(a[2], 'bin', 'python'))\n"
                    "elif a[:3] == ['-m', 'pip', 'install']:\n"
                    "    def stop(*_):\n        print('ERROR: Operation cancelled by user', file=sys.stderr)\n"
                    "        sys.exit(1)\n"
                    "    signal.signal(signal.SIGINT, stop)\n    print('started', flush=True)\n    time.sleep(30)\n")
    fake.chmod(0o755)
    venv = tmp_path / "venv"
    status, text = _ctrl_c_in_a_terminal(["make", "-s", "venv", "VENV=%s" % venv, "PYTHON=%s" % fake])
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == sig.SIGINT
    lines = [l for l in text.splitlines() if l.strip()]
    assert lines[0].startswith("make venv: building ") and lines[1:] == ["ERROR: Operation cancelled by user"], lines
    assert not [n for n in os.listdir(str(venv)) if n.startswith(".tipbot-venv")]
