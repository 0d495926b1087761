"""The margin sweep and the effects' costs (hostsim.studies.margins), on short runs."""
import dataclasses

import pytest

from hostsim.sim.scenario import Brick, floor_angle_rad, load_scenario
from hostsim.studies import margins
from hostsim.studies.report import brick_table, margins_section


def test_each_margin_moves_only_its_own_effect():
    base = dataclasses.replace(load_scenario(margins.BASE_SCENARIO), brick=Brick())
    sc = margins.margin_scenario(base, "backlash", 6.0, 0.005)
    assert sc.brick.backlash_deg == (6.0, 6.0, 6.0, 1.0) and not sc.brick.timed
    assert margins.margin_scenario(base, "deadband", 4.0, 0.005).brick.friction_deadband_pct == (4, 4, 4, 10)
    sc = margins.margin_scenario(base, "io_delay", 12.0, 0.005)
    assert sc.extra_delay_ticks == 2 and sc.io_latency_s == pytest.approx(0.002)
    sc = margins.margin_scenario(base, "push", -0.3, 0.005)
    assert sc.pushes[0].link == 3 and sc.pushes[0].impulse_n_s == -0.3 and sc.brick.ideal
    assert margins.margin_scenario(base, "gyro_drift", -0.01, 0.005).brick.gyro_bias_ramp_dps_s == -0.01
    assert margins.margin_scenario(base, "gyro_freeze", 100.0, 0.005).brick.gyro_freeze_s == pytest.approx(0.1)
    sc = margins.margin_scenario(base, "single_stall", 80.0, 0.005)
    assert sc.brick.single_stall_s == pytest.approx(0.08) and sc.brick.timed and sc.brick.tacho_access_s == (0, 0)
    # the firmware's own hold lifted to its bound for the search; the start pose kept
    assert sc.firmware_config["limits"]["max_stall_s"] == 0.5 and "start_pose_rad" in sc.firmware_config
    sc = margins.margin_scenario(base, "payload", 150.0, 0.005)
    assert (sc.payload.mass_kg, sc.payload.distance_m, sc.payload.t_off_s) == (0.15, 0.1, None) and sc.brick.ideal
    assert margins.margin_scenario(base, "payload", 0.0, 0.005).payload is None
    # on a slope the robot is released as far from the vertical as on the flat (th1 is from the
    # floor's normal), and the firmware is told the same start pose
    for key, sign in (("slope_up", 1), ("slope_down", -1)):
        sc = margins.margin_scenario(base, key, 8.0, 0.005)
        assert sc.slope.angle_deg == 8.0 * sign and sc.slope.ramp_start_m is None
        assert sc.x0_si[2] - floor_angle_rad(sc) == pytest.approx(base.x0_si[2])
        assert sc.firmware_config == base.firmware_config


def test_one_stall_holds_the_duties_and_the_robot_rides_it_out(monkeypatch):
    # 120 ms without the controller at t = 2.5 s (the simulation's clock: the calibration takes
    # the first 1.1 s), motors held: the robot stands on (physical gains),
    # the late tick's flags say how many periods the core predicted through
    import numpy as np
    from hostsim.sim.firmware_run import run_firmware
    monkeypatch.setattr(margins, "PUSH_AT_S", 2.5)
    base = dataclasses.replace(load_scenario(margins.BASE_SCENARIO), brick=Brick(), duration_s=4.0)
    sc = margins.margin_scenario(base, "single_stall", 120.0, 0.005)
    run = run_firmware(sc, gains_doc=margins._gains("gains/physical.json"))
    assert margins.balances(run) and run.completed
    skipped = run.flags[np.isfinite(run.flags)].astype(int) >> 7
    assert 22 <= skipped.max() <= 26 and (skipped > 0).sum() == 1


@pytest.mark.slow
def test_bisection_finds_the_push_the_robot_takes_and_the_report_shows_it(monkeypatch):
    monkeypatch.setattr(margins, "PUSH_AT_S", 0.5)
    res = margins.run_margins(gains_paths=("gains/physical.json",), coarse=True, ablation_gains=(), jobs=1,
                              effects=("push",), duration_s=2.0)
    rows = res["margins"]
    assert [r["sign"] for r in rows] == [1, -1]
    for r in rows:
        ok = [v for v, good in r["trials"] if good]
        bad = [v for v, good in r["trials"] if not good]
        assert ok[0] == 0.0 and bad and r["margin"] == max(ok) < min(bad) <= r["margin"] + r["tol"]
        assert 0.05 < r["margin"] < 1.0
    cells = margins.margin_cells(res, "physical")
    assert cells["push"].startswith("%.3g (" % min(r["margin"] for r in rows)) and cells["backlash"] == "-"
    figures, bound = cells["push"].split("; ")
    assert all(len(v.strip("+-")) <= 5 for v in figures.split(" (")[1].rstrip(")").split(", "))   # 3 digits
    # beside the bound no law passes on the study's plant (push_limit's LP)
    assert res["_meta"]["push_bound_n_s"] == pytest.approx(0.250, abs=0.002)
    assert bound == "%.0f %% of the LP bound %.3f" % (100 * min(r["margin"] for r in rows) / res["_meta"]["push_bound_n_s"],
                                                    res["_meta"]["push_bound_n_s"])
    text = "\n".join(margins_section(res))
    assert "push on link 3 (N s)" in text and "robustness/margins.png" in text


@pytest.mark.slow
def test_bisection_finds_the_payload_and_the_slope_the_robot_takes():
    res = margins.run_margins(gains_paths=("gains/physical.json",), coarse=True, ablation_gains=(), jobs=1,
                              effects=("payload", "slope_down"), duration_s=4.0)
    rows = {r["effect"]: r for r in res["margins"]}
    for r in rows.values():
        ok = [v for v, good in r["trials"] if good]
        bad = [v for v, good in r["trials"] if not good]
        assert ok[0] == 0.0 and bad and r["margin"] == max(ok) < min(bad) <= r["margin"] + r["tol"]
    # inside the searches' ends (1 kg at 10 cm is 1 N m: five times what the joint motors hold;
    # 45 degrees), beyond a few grams and degrees
    assert 30 <= rows["payload"]["margin"] < 900 and 5 <= rows["slope_down"]["margin"] < 44
    cells = margins.margin_cells(res, "physical")
    assert cells["payload"] == "%.3g" % rows["payload"]["margin"] and cells["slope_up"] == "-"
    assert "payload at the top of link 3 (g)" in margins.margin_table(res)


def test_ablation_rows_switch_the_effects_as_named():
    base = dataclasses.replace(load_scenario(margins.BASE_SCENARIO), duration_s=0.3)
    shipped = margins.ablation_run(("physical", "gains/physical.json", base, None, 0, False))
    assert shipped["off"] == "none (all on)" and shipped["overrun_fraction"] is not None
    alone = margins.ablation_run(("physical", "gains/physical.json", base, "only backlash", 0, True))
    but = margins.ablation_run(("physical", "gains/physical.json", base, "timing", 0, True))
    assert alone["overrun_fraction"] == 0.0 and but["overrun_fraction"] == 0.0     # no timing in either
    res = {"ablation": [margins.aggregate([r]) for r in (shipped, alone, but)]}
    order = [r["off"] for r in margins.ranked_ablation(res)]
    assert order == ["none (all on)", "timing", "only backlash"]
    assert margins.costliest(res, "physical") == ["backlash"]
    assert "all but timing" in margins.ablation_table(res)


def test_the_report_lists_the_realistic_bricks_values_with_their_sources():
    brick = load_scenario(margins.BASE_SCENARIO).brick
    table = brick_table({"brick": dataclasses.asdict(brick)})
    rows = table.splitlines()[2:]
    assert len(rows) == len(brick.sources) - 1              # every effect but the (off) timeout fault
    assert "| `backlash_deg` | [3.0, 3.0, 3.0, 0.5] | ev3-hardware.md:" in table
    assert all("ev3-hardware.md" in r or "assumption" in r or "estimate" in r for r in rows)
