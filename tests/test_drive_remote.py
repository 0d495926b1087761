"""`tipbot-host drive` (issue 21): keys to commands, and scripted keystrokes driving the firmware
on the real-time fake robot."""
import os
import socket
import subprocess
import sys
import time

import pytest

from conftest import PHYSICAL_GAINS, REPO
from hostsim.logs.drive import SPEED_STEP_MPS, YAW_STEP_DPS, apply_key
from tipbot_fw.record.logfile import read_log


def test_keys_change_speed_and_turn_by_their_steps():
    s = (0.0, 0.0)
    for key in ("w", "w", "\x1b[D", "a", "d"):
        s = apply_key(s, key)
    assert s == (2 * SPEED_STEP_MPS, YAW_STEP_DPS)
    assert apply_key(s, "x") == s and apply_key(s, " ") == (0.0, 0.0)
    assert apply_key((0.0, 0.0), "\x1b[B") == (-SPEED_STEP_MPS, 0.0) and apply_key((0.0, 0.0), "S") == (-0.05, 0.0)


def free_udp_port():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.slow
def test_scripted_keystrokes_drive_the_real_time_fake_robot(tmp_path):
    sim_brick = __import__("test_deploy").sim_brick
    scenario = tmp_path / "loopback.json"
    scenario.write_text('{"name": "loopback", "seed": 1}\n')
    config, sysfs, log = str(tmp_path / "robot-config.json"), str(tmp_path / "sysfs"), str(tmp_path / "run.log")
    port = free_udp_port()
    robot = sim_brick.FakeRobot(sysfs, str(scenario), config, duration_s=60)
    try:
        firmware = [sys.executable, "-m", "tipbot_fw", "run", "--gains", PHYSICAL_GAINS, "--config", config,
                    "--sysfs-root", sysfs, "--duration", "6", "--log", log, "--remote", str(port)]
        drive = subprocess.Popen([sys.executable, "-m", "hostsim", "drive", "--to", "127.0.0.1", "--port", str(port),
                                  "--"] + firmware, cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, universal_newlines=True)
        time.sleep(3.0)                 # the start: calibration, let-go
        drive.stdin.write("www")        # 0.15 m/s forward
        drive.stdin.flush()
        time.sleep(1.5)
        drive.stdin.write(" ")          # stop
        drive.stdin.flush()
        out, _ = drive.communicate(timeout=60)
    finally:
        robot_out = robot.stop()
    assert drive.returncode == 0, out + robot_out
    assert "drive: speed +0.15 m/s, turn +0 deg/s" in out and "commands obeyed from 127.0.0.1" in out, out
    header, rows = read_log(log)
    names = [c["name"] for c in header["columns"]]
    v_ref = rows[:, names.index("ref_v_r")]
    assert v_ref.max() == pytest.approx(0.15, abs=0.01) and abs(v_ref[-1]) < 1e-3
    d = rows[:, names.index("enc_r")] - header["encoder_offsets"][0]
    assert abs(d[-1]) > 50             # the fake robot's wheel turned (counts)
