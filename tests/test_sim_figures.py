"""What the report's figures and tables show (hostsim.studies.plots, hostsim.studies.runner): captions cite the
paper's figure of their own scenario only, the whole input demand is on the figure, short
transients get an inset, a run stopped early fills the time axis, stop limits are marked, axes and columns carry units."""
import dataclasses

import numpy as np
import pytest

from hostsim.sim import metrics
from hostsim.sim.result import RunResult
from hostsim.sim.scenario import parse_scenario
from hostsim.studies import plots, runner

U_MAX_V = 7.6


@pytest.fixture
def figures(monkeypatch):
    """The figures the plot functions would save, kept open for inspection."""
    kept = []

    def keep(fig, path):
        kept.append(fig)
        return path
    monkeypatch.setattr(plots, "_write", keep)
    yield kept
    for fig in kept:
        plots.plt.close(fig)


def test_captions_cite_the_paper_figure_of_their_own_scenario_only():
    assert plots.caption("section7", "estimation_errors").endswith("cf. paper Figure 6")
    assert plots.caption("section8", "inputs").endswith("cf. paper Figure 10")
    assert plots.caption("appendix_d", "compare_firmware").endswith("firmware runs, cf. paper Figure A1")
    for scenario, key in (("section7", "inputs"), ("section7", "positions"), ("section8", "states_estimates"),
                          ("section8_physical", "positions"), ("appendix_d", "velocities")):
        assert "Figure" not in plots.caption(scenario, key), (scenario, key)


def section7_like_runs(n=800, ts=0.005):
    """A linear run whose law demands 71.5 V at the second tick and whose estimate converges in
    a few ticks, and a noisy firmware run."""
    t = np.arange(n) * ts
    rng = np.random.default_rng(0)
    x = np.zeros((n, 10))
    x[:, 2] = 0.1 * np.exp(-t)
    err = np.outer(0.2 ** np.arange(n), np.ones(10)) * 0.01
    u_unsat = np.zeros((n, 5))
    u_unsat[:, 0] = 2.0 * np.exp(-t)
    u_unsat[1, 0] = 71.5
    u = np.clip(u_unsat, -U_MAX_V, U_MAX_V)
    none = np.zeros((n, 5))
    lin = RunResult(t_s=t, x=x, u=u, w=none, completed=True, xhat=x + err, u_unsat=u_unsat)
    fw_u = np.clip(rng.normal(0, 4, (n, 5)), -U_MAX_V, U_MAX_V)
    fw = RunResult(t_s=t, x=x, u=fw_u, w=none, completed=True, xhat=x + rng.normal(0, 0.003, (n, 10)),
                   u_unsat=1.5 * fw_u)
    return {"linear/optimal": lin, "firmware/optimal": fw}


def test_the_whole_demand_is_on_the_inputs_figure(figures):
    sc = parse_scenario({"duration_s": 4.0}, "<test>")
    plots.inputs(sc, section7_like_runs(), U_MAX_V, "inputs.png")
    fig = figures[0]
    wheel = fig.axes[0]
    assert wheel.get_ylim()[1] >= 2 * U_MAX_V              # the rails with room around them
    insets = [a for a in wheel.child_axes]
    assert len(insets) == 1 and insets[0].get_ylim()[1] >= 71.5
    assert any("71.5 V" in t.get_text() for t in insets[0].texts)
    # the linear run is drawn above the nonlinear band and the firmware run, and shows
    styles = {line.get_label(): line for line in wheel.get_lines() if not line.get_label().startswith("_")}
    assert styles["linear/optimal"].get_zorder() > styles["firmware/optimal"].get_zorder()
    assert plots.MODE_ZORDER["linear"] > plots.MODE_ZORDER["nonlinear"]
    assert plots.MODE_WIDTH["nonlinear"] > 2 * plots.MODE_WIDTH["linear"]


def test_a_transient_of_a_few_ticks_gets_an_inset(figures):
    sc = parse_scenario({"duration_s": 4.0}, "<test>")
    runs = section7_like_runs()
    assert plots.transient_window_s(runs, 0.005) == pytest.approx(0.05)     # 10 ticks at least
    plots.estimation_errors(sc, runs, "errors.png")
    panels = [a for a in figures[0].axes if a.child_axes]
    assert len(panels) == 10
    assert panels[0].child_axes[0].get_xlim() == pytest.approx((0, 0.05))
    # a slow error gets none: the run's own time axis shows it
    slow = {k: dataclasses.replace(v, xhat=v.x + 0.01 * np.exp(-v.t_s)[:, None]) for k, v in runs.items()}
    plots.estimation_errors(sc, slow, "errors.png")
    assert not [a for a in figures[1].axes if a.child_axes]


def test_a_run_stopped_early_fills_the_time_axis(figures):
    # the firmware's safe stop after 0.2 s of a 30 s scenario (the realistic brick's overruns):
    # the axis ends just past the stop, not at 30 s; a run that goes on keeps the whole duration
    sc = parse_scenario({"duration_s": 30.0}, "<test>")
    runs = section7_like_runs(n=40)
    plots.states_estimates(sc, runs, "states.png")
    assert figures[0].axes[0].get_xlim() == pytest.approx((0, 1.05 * 39 * 0.005))
    plots.states_estimates(parse_scenario({"duration_s": 4.0}, "<test>"), section7_like_runs(), "states.png")
    assert figures[1].axes[0].get_xlim() == pytest.approx((0, 4.0))


def test_region_of_attraction_bars_at_the_stop_limit_are_marked(figures):
    rows = [{"gains": "physical", "mode": "firmware", "angle": a, "sign": s, "max_recovered_rad": v, "limit_rad": lim}
            for a, v, lim in (("th1", 0.22, 0.6), ("th3", 1.2, 1.2)) for s in (1, -1)]
    plots.roa_figure(rows, "roa.png")
    ax = figures[0].axes[0]
    hatched = sorted(round(b.get_height(), 2) for b in ax.patches if b.get_hatch())
    assert hatched == [1.2, 1.2]
    assert "firmware stop limit" in " ".join(t.get_text() for t in ax.get_legend().get_texts())


def test_monte_carlo_histograms_say_what_they_count(figures):
    rows = [{"success": True, "peak_abs_th1_rad": 0.01 * k, "peak_abs_u_v": 4 + 0.1 * k} for k in range(10)]
    plots.montecarlo_figure({"physical": {"runs": rows}}, "mc.png")
    hist_tilt, hist_u, scatter = figures[0].axes
    assert hist_tilt.get_ylabel() == hist_u.get_ylabel() == "runs"
    assert "[rad]" in hist_tilt.get_xlabel() and "[V]" in hist_u.get_xlabel()


def test_both_gains_files_histograms_share_their_bins(figures):
    a = [{"success": True, "peak_abs_th1_rad": 0.01 * k, "peak_abs_u_v": 4 + 0.1 * k} for k in range(10)]
    b = [{"success": True, "peak_abs_th1_rad": 0.05 + 0.002 * k, "peak_abs_u_v": 2 + 0.5 * k} for k in range(10)]
    plots.montecarlo_figure({"physical": {"runs": a}, "paper": {"runs": b}}, "mc.png")
    for ax in figures[0].axes[:2]:
        widths = {round(p.get_width(), 12) for p in ax.patches}
        assert len(widths) == 1, widths                      # one bin width for both files' bars


def test_inputs_say_when_nothing_saturated_and_the_disturbance_band_is_named(figures):
    sc = parse_scenario({"duration_s": 4.0, "disturbances": [{"t_start_s": 1.0, "t_end_s": 2.0,
                                                              "w_v": [1, 1, 0, 0, 0]}]}, "<test>")
    runs = section7_like_runs()
    plots.inputs(sc, runs, U_MAX_V, "inputs.png")            # the demand is cut: dotted lines
    top = figures[0].axes[0]
    assert "no input saturated" not in top.get_title(loc="left")
    assert any(line.get_linestyle() == ":" for line in top.get_lines())
    legend = [t.get_text() for t in figures[0].legends[0].get_texts()]
    assert "input disturbance (1, 1 V)" in legend
    # within the rails, a demand that differs from the input by a duty's rounding is no cut
    calm = {k: dataclasses.replace(v, u_unsat=0.99 * v.u + 0.02) for k, v in runs.items()}
    plots.inputs(sc, calm, U_MAX_V, "inputs.png")
    assert "no input saturated" in figures[1].axes[0].get_title(loc="left")
    assert not any(line.get_linestyle() == ":" for line in figures[1].axes[0].get_lines())


def test_the_pd_is_drawn_apart_from_the_optimal_controller_in_a_comparison():
    assert plots._style("firmware/pd", solo=True)["color"] != plots._style("firmware/optimal", solo=True)["color"]
    assert plots._style("firmware/pd", solo=True)["linestyle"] == "--"


def test_summary_columns_carry_units_and_split_the_estimation_error_by_unit():
    names = [name for name, _ in runner.SUMMARY_COLUMNS]
    for name in names[2:]:
        assert name.split()[-1] in ("rad", "V", "%", "s", "m", "m/s", "rad/s"), name
    t = np.arange(400) * 0.005
    x = np.zeros((400, 10))
    err = np.zeros(10)
    err[[0, 2, 5, 7]] = [0.002, 0.03, 0.4, 3.0]          # m, rad, m/s, rad/s
    run = RunResult(t_s=t, x=x, u=np.zeros((400, 5)), w=np.zeros((400, 5)), completed=True, xhat=x + err)
    m = metrics.compute(run, parse_scenario({"duration_s": 2.0}, "<test>"), U_MAX_V)
    assert m["final_est_error_by_unit"] == {"m": 0.002, "rad": 0.03, "m/s": 0.4, "rad/s": 3.0}
    row = runner.summary_rows({"runs": {"linear/optimal": m}})[0]
    assert row[-4:] == ["2.0e-03", "3.0e-02", "4.0e-01", "3.0e+00"]


def test_margins_are_labelled_to_three_digits_in_rows_of_five_panels(figures):
    from hostsim.studies.margins import MARGINS
    rows = [{"gains": "physical", "effect": m.key, "sign": s, "margin": 32.8125, "at_least": False}
            for m in MARGINS for s in m.signs]
    plots.margins_figure({"margins": rows, "_meta": {"duration_s": 30}}, "unused.png", MARGINS)
    fig = figures[-1]
    shown = [a for a in fig.axes if a.get_visible()]
    assert len(shown) == len(MARGINS) and len({round(a.get_position().y0, 3) for a in shown}) == -(-len(MARGINS) // 5)
    labels = {t.get_text() for a in shown for t in a.texts}
    assert labels == {"32.8"}


def test_a_long_run_shows_its_last_second_enlarged_and_a_short_one_does_not(figures):
    # 50 s of a 15 Hz dither draw a solid band; the inset redraws the panel's own lines in the last second
    sc = parse_scenario({"duration_s": 50.0}, "<test>")
    t = np.arange(10000) * 0.005
    x = np.zeros((len(t), 10))
    x[:, 9] = 0.2 * np.sin(2 * np.pi * 15 * t)
    run = RunResult(t_s=t, x=x, u=np.zeros((len(t), 5)), w=np.zeros((len(t), 5)), completed=True)
    plots.velocities(sc, {"firmware/optimal": run}, "velocities.png")
    panels = [a for a in figures[0].axes if a.get_visible() and a.get_ylabel()]
    assert len(panels) == 5 and all(len(a.child_axes) == 1 for a in panels)
    zoom = panels[-1].child_axes[0]
    assert zoom.get_xlim() == pytest.approx((49.0 - 0.005, 50.0 - 0.005))
    assert zoom.get_title() == "last 1 s, enlarged"
    (line,) = zoom.get_lines()
    assert len(line.get_xdata()) == 201 and np.ptp(line.get_ydata()) == pytest.approx(0.4, abs=0.01)
    plots.velocities(parse_scenario({"duration_s": 4.0}, "<test>"), section7_like_runs(), "velocities.png")
    assert not [a for a in figures[1].axes if a.child_axes]


def test_a_long_caption_gets_a_smaller_font_not_cut():
    fig, _ = plots._grid(4, 1, "x" * 80)
    assert fig._suptitle.get_fontsize() == pytest.approx(11.0 * 68 / 80)
    plots.plt.close(fig)
    fig, _ = plots._grid(4, 1, "short")
    assert fig._suptitle.get_fontsize() == 11.0
    plots.plt.close(fig)
