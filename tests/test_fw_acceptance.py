"""The firmware's acceptance run: the unmodified firmware, device layer included, on the
simulated robot through the fake EV3 sysfs tree.

From th1 = 0.1 rad (held there during the gyro calibration, then released), with the paper's
1 V disturbance on both wheels for 0.5 s, each shipped gains file keeps the robot up for 10 s
and the state settles near zero; each control tick does at most 5 sysfs reads and 4 writes
(the battery is read about once a second, after a tick's writes, in the loop's slack).
"""
import numpy as np
import pytest

from hostsim.sim.firmware_run import run_firmware
from hostsim.sim.scenario import parse_scenario

TICK_READS = ("position", "bin_data")
BATTERY = "voltage_now"


def acceptance_scenario(gains):
    return parse_scenario({
        "name": "acceptance", "duration_s": 10.0, "gains": gains,
        "x0_si": [0, 0, 0.1, 0, 0, 0, 0, 0, 0, 0],
        "disturbances": [{"t_start_s": 2.0, "t_end_s": 2.5, "w_v": [1, 1, 0, 0, 0]}],
        "sensors": {"gyro_bias_dps": 0.8, "gyro_noise_dps": 0.3},
        "modes": ["firmware"], "seed": 11})


@pytest.fixture(scope="module", params=["gains/paper.json", "gains/physical.json"])
def run(request):
    sc = acceptance_scenario(request.param)
    return run_firmware(sc, sysfs=True, keep_rows=False)


def test_keeps_the_robot_up_for_10_s_and_settles_near_zero(run):
    assert run.exit_code == 0 and run.stop_reason == "completed"
    t, x = run.t_s, run.x
    assert t[-1] == pytest.approx(10.0, abs=0.006)
    assert np.abs(x[:, 2]).max() <= 0.1 + 1e-9              # never leans further than released
    last = x[t >= 8.0]
    assert np.abs(last[:, 2]).max() < 0.03                   # th1 within 0.03 rad of upright
    assert np.abs(last[:, 3:5]).max() < 0.05                 # joints within 0.05 rad
    assert np.abs(last[:, 5:7]).max() < 0.1                  # wheels nearly still (m/s)
    assert np.abs(last[:, 0:2] - x[0, 0:2]).max() < 0.15     # within 15 cm of where it started
    # The disturbance did reach the plant (the test is not vacuous).
    assert np.abs(run.w[(t >= 2.0 - 1e-9) & (t < 2.5 - 1e-9), 0]).min() == 1.0


def test_each_tick_reads_at_most_5_and_writes_at_most_4_sysfs_attributes(run):
    iterations = run.io_per_iteration
    assert len(iterations) > 1900
    battery_reads = 0
    for ops in iterations:
        reads = [rel for op, rel, _ in ops if op == "pread"]
        writes = [rel for op, rel, _ in ops if op == "pwrite"]
        tick_reads = [r for r in reads if r.endswith(TICK_READS)]
        battery_reads += sum(r.endswith(BATTERY) for r in reads)
        assert len(tick_reads) == 5, reads
        assert len(reads) - len(tick_reads) <= 1                   # at most the battery, after the writes
        assert len(writes) <= 4 and all(w.endswith("duty_cycle_sp") for w in writes), writes
        # order within an iteration: the 5 reads, then the writes, then the battery
        kinds = [rel.endswith(TICK_READS) for op, rel, _ in ops if op == "pread" or op == "pwrite"]
        assert kinds[:5] == [True] * 5
    assert 8 <= battery_reads <= 11                                # about once a second for 10 s
