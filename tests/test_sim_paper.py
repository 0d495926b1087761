"""Short versions of the paper's scenarios, judged on their metrics (not on pictures).

Linear and nonlinear (ideal measurement) runs must do what the design promises. The
firmware-in-the-loop runs are held to what must be true whatever the firmware's tuning
(saturated inputs, estimate starting at the first measurement, a clean stop), and where they
start near the equilibrium (Section 8, Appendix D) they must balance.
"""
from dataclasses import replace

import numpy as np
import pytest

from hostsim.errors import TipbotError
from hostsim.sim import metrics
from hostsim.sim.firmware_run import run_firmware
from hostsim.sim.linear_sim import simulate_linear, simulate_nonlinear
from hostsim.model.pd import pd_for_gains
from hostsim.studies.runner import run_scenario, scenario_metrics
from hostsim.sim.scenario import load_scenario
from tipbot_fw.gains import load_gains
from conftest import gains_path

U_MAX = 7.6
ACT = [0, 1, 3, 4]


def shortened(name, duration_s, shift_s=0.0):
    """The scenario cut to duration_s, its disturbances moved earlier by shift_s."""
    sc = load_scenario(name)
    return replace(sc, duration_s=duration_s, disturbances=tuple(
        replace(d, t_start_s=d.t_start_s - shift_s, t_end_s=d.t_end_s - shift_s) for d in sc.disturbances))


def run_metrics(sc, modes):
    gs, runs = run_scenario(sc, modes=modes, sysfs=False)
    return gs, runs, scenario_metrics(sc, gs, runs)


@pytest.fixture(scope="module")
def section7():
    sc = load_scenario("section7")
    return sc, run_metrics(sc, ["linear", "nonlinear"])


def test_section7_demands_about_20_volts_at_the_first_step(section7):
    sc, (gs, runs, m) = section7
    # |K x(0)| from the printed x(0) is 19-25 V (shared/paper/README.md), far above 7.6 V.
    k_x0 = np.abs(gs.K @ np.array(sc.x0_si))[ACT]
    assert 15.0 < k_x0.max() < 30.0
    lin = m["linear/optimal"]
    assert max(abs(v) for v in lin["u0_unsat_v"]) > 15.0
    assert max(lin["peak_abs_u_v"]) == pytest.approx(U_MAX)


@pytest.mark.parametrize("label", ["linear/optimal", "nonlinear/optimal"])
def test_section7_recovers_despite_saturation(section7, label):
    sc, (gs, runs, m) = section7
    r = m[label]
    assert r["upright"]
    assert max(r["peak_abs_u_v"]) <= U_MAX + 1e-9
    assert r["saturated_fraction"] > 0.0
    assert r["settle_time_s"] is not None and r["settle_time_s"] < 1.0
    assert r["final_abs_th1_rad"] < 0.005
    assert r["final_abs_d_m"] < 0.01


def test_section7_detector_error_converges_despite_disturbance_and_saturation(section7):
    sc, (gs, runs, m) = section7
    lin = m["linear/optimal"]
    assert max(lin["est_error_initial"]) > 0.5           # x~(0) is far from x(0)
    assert lin["est_error_converged"] and lin["final_est_error"] < 1e-9
    # w^_k is w_k one tick later, exactly, once the estimate has converged.
    assert lin["w_hat_error_v"] < 1e-6
    run = runs["linear/optimal"]
    e = np.abs(run.xhat - run.x).max(axis=1)
    assert e[40] < 1e-6 * e[0]                            # detector poles at 0.2: fast
    # The nonlinear plant is not the detector's model: the error is small, not zero.
    assert m["nonlinear/optimal"]["final_est_error"] < 1e-3


def test_section8_short_rejects_the_wheel_disturbance():
    sc = shortened("section8", 8.0, shift_s=17.0)        # disturbance from 3 to 8 s
    gs, runs, m = run_metrics(sc, ["linear", "nonlinear"])
    for label in ("linear/optimal", "nonlinear/optimal"):
        r = m[label]
        assert r["upright"]
        assert max(r["peak_abs_u_v"]) < U_MAX                 # no saturation from 0.017 rad
        assert r["disturbed_peak_dev"][2] < 0.005             # th1 barely moves under 1 V
        assert r["final_abs_d_m"] < 0.01
    a, b = runs["linear/optimal"].x, runs["nonlinear/optimal"].x
    assert np.max(np.abs(a[:, 2] - b[:, 2])) < 1e-3


@pytest.mark.slow
def test_appendix_d_short_optimal_beats_pd():
    sc = shortened("appendix_d", 5.0, shift_s=4.0)         # disturbance from 1 to 3 s
    gs, runs, m = run_metrics(sc, ["linear"])
    opt, pd = m["linear/optimal"], m["linear/pd"]
    assert opt["upright"] and pd["upright"]
    # The optimal law cancels the matched disturbance one tick after it appears; the PD
    # (no K_w, no integral action) lets the wheels run off and the links lean.
    assert pd["disturbed_peak_dev"][0] > 0.01                          # > 1 cm
    assert pd["disturbed_peak_dev"][0] > 20 * opt["disturbed_peak_dev"][0]
    assert pd["disturbed_peak_dev"][2] > 3 * opt["disturbed_peak_dev"][2]
    assert max(opt["peak_abs_u_v"]) < U_MAX and max(pd["peak_abs_u_v"]) < U_MAX


@pytest.mark.slow
def test_pd_baseline_is_stable_and_close_to_the_lq_cost():
    for variant in ("paper", "physical"):
        pd = pd_for_gains(gains_path(variant))
        assert pd["spectral_radius"] < 1.0
        assert 1.0 < pd["cost"] / pd["lqr_cost"] < 1.5


@pytest.mark.parametrize("name, duration, shift", [("section7", 1.0, 0.0), ("section8", 2.0, 19.0),
                                                    ("appendix_d", 2.0, 4.5)])
def test_firmware_runs_of_the_paper_scenarios_keep_the_invariants(name, duration, shift):
    sc = shortened(name, duration, shift)
    run = run_firmware(sc, sysfs=False)
    n = len(run.t_s)
    assert n >= 1 and run.exit_code in (0, 6)                       # completed, or a safety stop
    assert np.all(np.abs(run.u[:, ACT]) <= U_MAX + 1e-9)
    assert np.all(np.abs(run.u_applied[:, ACT]) <= U_MAX + 1e-9)
    # The estimate starts at the start pose the firmware is told, at rest, not at the
    # scenario's x~(0).
    np.testing.assert_allclose(run.xhat[0, 2:5], sc.x0_si[2:5], atol=1e-9)
    assert np.all(run.xhat[0, 5:] == 0)
    # The wheel origin (hostsim.sim.firmware_run): shifted by d_origin_m, the firmware's estimated d is the
    # plant's, to an encoder count and the th1 estimate's error times R_w.
    early = run.t_s <= 0.3
    assert np.abs(run.xhat[early, :2] - run.x[early, :2]).max() < 0.002


@pytest.mark.parametrize("name", ["section8", "appendix_d"])
def test_firmware_balances_with_the_shipped_gains(name):
    sc = shortened(name, 4.0, shift_s={"section8": 18.0, "appendix_d": 3.0}[name])
    run = run_firmware(sc, sysfs=False, keep_rows=False)
    m = metrics.compute(run, sc, U_MAX)
    assert m["upright"] and m["final_abs_th1_rad"] < 0.05


def test_linear_and_nonlinear_agree_near_equilibrium():
    sc = load_scenario("near_equilibrium")
    g = load_gains(sc.gains)
    lin, nl = simulate_linear(g, sc), simulate_nonlinear(g, sc)
    assert np.max(np.abs(lin.x[:, 2] - nl.x[:, 2])) < 2e-4
    assert np.max(np.abs(lin.u - nl.u)) < 0.05


@pytest.mark.slow
def test_the_reference_governor_keeps_section7_within_the_motors():
    """Section 7's initial state asks ~20 V of the law; led back along rest points it can
    reach, the law stays within 7.6 V (from a correct first estimate: the printed x~(0) is
    half of x(0), and the detector's first correction alone saturates three ticks)."""
    from hostsim.sim.governor import ReferenceGovernor
    sc = replace(load_scenario("section7_governed"), xhat0_si=None)
    g = load_gains(sc.gains)
    plain = simulate_linear(g, replace(sc, reference_governor=False))
    assert np.abs(plain.u_unsat[:, ACT]).max() > 20.0
    for run in (simulate_linear(g, sc), simulate_nonlinear(g, sc)):
        assert np.abs(run.u_unsat[:, ACT]).max() < U_MAX
        assert np.abs(run.x[-1, :2]).max() < 0.01 and np.abs(run.x[-1, 2:5]).max() < 0.01
    gov = ReferenceGovernor(g, sc.x0_si)
    assert gov.peak0_v < U_MAX and gov.kappa == 1.0
    # the rest point it starts from: the robot rolled ahead, bent links held by their motors
    assert gov.x_e[0] > 0.1 and np.any(gov.u_e != 0)


@pytest.mark.slow      # three runs of 50 s, the whole scenario (make test-fast stays under 90 s)
def test_the_host_modes_run_the_firmwares_default_estimator():
    # linear and nonlinear with the Kalman filter of the gains' kalman block (in floats, ideal
    # measurement): they balance Section 8 as the firmware does, their estimate converges, and
    # the same scenario's firmware run (fixed point, quantized sensors) stays close to them
    sc = load_scenario("section8")
    g = load_gains(sc.gains)
    fw = run_firmware(sc, sysfs=False)
    for sim in (simulate_linear, simulate_nonlinear):
        run = sim(g, sc, estimator="kalman")
        assert run.completed
        late = slice(3 * len(run.t_s) // 4, None)
        assert np.abs(run.xhat[late] - run.x[late]).max() < 1e-5
        assert np.abs(run.u[:, ACT]).max() <= U_MAX + 1e-12
        n = min(len(run.t_s), len(fw.t_s))
        assert np.abs(run.x[:n, 2] - fw.x[:n, 2]).max() < 0.01      # th1 within 10 mrad of the firmware's
    with pytest.raises(TipbotError, match="estimator"):
        simulate_linear(g, sc, estimator="observer")
    # `python -m hostsim run/sim --host-estimator kalman`: its own labels, the scenario's bounds on them
    # (the labels only: 2 s of the scenario, not its 50, as the runs above have shown how it runs)
    _, runs = run_scenario(replace(sc, duration_s=2.0), modes=["nonlinear", "firmware"], sysfs=False,
                           host_estimator="kalman")
    assert sorted(runs) == ["firmware/optimal", "nonlinear-kalman/optimal"]
