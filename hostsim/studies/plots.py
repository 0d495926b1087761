"""PNG figures laid out like the paper's (matplotlib, Agg backend; no display needed).

- ``states_estimates.png``: each state against its estimate (10 panels a-j), as Figure 5;
- ``estimation_errors.png``: x~ - x, as Figure 6, with an inset on the detector's first ticks
  when its transient is too short to see on the run's time axis;
- ``positions.png``, ``velocities.png``, ``inputs.png``: as Figures 8, 9 and 10 (the paper
  draws its simulation in red and its experiment in blue: here the linear run is red and
  the firmware-in-the-loop run blue, the nonlinear ideal-measurement run green); inputs
  before saturation dotted where saturation cut it, and a demand beyond the axis drawn whole in an inset of the start;
- ``compare_<mode>.png``: optimal against PD, as Figure A1;
- robustness figures for the Monte Carlo and the region of attraction.

A caption cites a paper figure only for the scenario that figure shows (PAPER_FIGURES).
Wheel displacements and speeds are drawn in cm and cm/s, as in the paper; the shaded band
marks the input disturbance.
"""
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

STATE_LABELS = (r"$\delta_r$ [cm]", r"$\delta_l$ [cm]", r"$\theta_1$ [rad]", r"$\theta_2$ [rad]",
                r"$\theta_3$ [rad]", r"$\dot\delta_r$ [cm/s]", r"$\dot\delta_l$ [cm/s]",
                r"$\dot\theta_1$ [rad/s]", r"$\dot\theta_2$ [rad/s]", r"$\dot\theta_3$ [rad/s]")
INPUT_LABELS = ((0, r"$u_1$ right wheel [V]"), (1, r"$u_2$ left wheel [V]"), (3, r"$u_3$ link 2 [V]"),
                (4, r"$u_4$ link 3 [V]"))
DISPLAY = np.array([100, 100, 1, 1, 1, 100, 100, 1, 1, 1], dtype=float)
MODE_COLORS = {"linear": "tab:red", "nonlinear": "tab:green", "firmware": "tab:blue"}
CONTROLLER_STYLE = {"optimal": "-", "pd": "--"}
CONTROLLER_SOLO_COLORS = {"pd": "k"}
LETTERS = "abcdefghij"


# The linear and nonlinear runs often coincide: the nonlinear one is a wide pale band and the
# linear one a thin line on top of it, so both stay visible; the noisy firmware run underneath.
MODE_WIDTH = {"linear": 1.1, "nonlinear": 4.0, "firmware": 0.8}
MODE_ZORDER = {"linear": 4, "nonlinear": 3, "firmware": 2}
MODE_ALPHA = {"linear": 1.0, "nonlinear": 0.5, "firmware": 1.0}

# The paper's figure that shows each scenario's experiment; other scenarios cite none.
PAPER_FIGURES = {
    "section7": {"states_estimates": "5", "estimation_errors": "6"},
    "section8": {"positions": "8", "velocities": "9", "inputs": "10"},
    "appendix_d": {"compare": "A1"},
}
WHAT = {"states_estimates": "states (solid) and estimates (dotted)", "estimation_errors": "estimation errors x~ - x",
        "positions": "positions", "velocities": "velocities", "inputs": "control inputs (dotted: the demand where saturation cut it)",
        "compare": "optimal controller (solid) vs PD (dashed)"}


def caption(scenario, key):
    """'section7: estimation errors x~ - x, cf. paper Figure 6' (key: a scenario_plots key)."""
    kind = "compare" if key.startswith("compare_") else key
    what = WHAT.get(kind, key.replace("_", " "))
    if kind == "compare":
        what += ", %s runs" % key[len("compare_"):]
    fig = PAPER_FIGURES.get(scenario, {}).get(kind)
    return "%s: %s%s" % (scenario, what, ", cf. paper Figure %s" % fig if fig else "")


def _style(label, solo=False):
    """Line style of a run; solo: the only mode in the figure (no band to tell it from another),
    where the controllers differ by colour too (the PD's dashed line in black: a dash alone is
    lost in a noisy trace of the same colour)."""
    mode, controller = label.split("/")
    color = CONTROLLER_SOLO_COLORS.get(controller) if solo else None
    return dict(color=color or MODE_COLORS.get(mode, "k"), linestyle=CONTROLLER_STYLE.get(controller, "-"),
                linewidth=1.0 if solo else MODE_WIDTH.get(mode, 1.0), zorder=MODE_ZORDER.get(mode, 2),
                alpha=1.0 if solo else MODE_ALPHA.get(mode, 1.0))


def _time_end(sc, runs):
    """The time axis' end: the scenario's duration, unless every run stopped before half of it
    (the firmware's safe stops): then a little past the last one's end, which would otherwise
    be a smear at the left edge (a stop after 0.2 s of a 30 s scenario)."""
    last = max([float(r.t_s[-1]) for r in runs.values() if len(r.t_s)] or [sc.duration_s])
    return sc.duration_s if last > 0.5 * sc.duration_s else max(1.05 * last, 0.05)


def _shade(ax, sc, runs):
    """The scenario's input disturbances as grey bands, named once in the legend."""
    end = _time_end(sc, runs)
    named = False
    for d in sc.disturbances:
        if any(d.w_v) and d.t_start_s < end:
            volts = ", ".join("%g" % v for v in d.w_v if v)
            ax.axvspan(d.t_start_s, min(d.t_end_s, end), color="0.88", zorder=0,
                       label=None if named else "input disturbance (%s V)" % volts)
            named = True
    ax.set_xlim(0.0, end)


def _grid(nrows, ncols, title, height=2.0):
    fig, axes = plt.subplots(nrows, ncols, figsize=(6.0 * ncols, height * nrows), sharex=True, squeeze=False)
    # about 68 characters of 11 pt fit a 6-inch column: a longer caption gets a smaller font, not cut
    fig.suptitle(title, fontsize=min(11.0, 11.0 * 68 * ncols / max(1, len(title))))
    # Fixed margins: tight_layout costs more than drawing these figures.
    top = 1.0 - 0.8 / (height * nrows)
    fig.subplots_adjust(left=0.09 / ncols + 0.03, right=0.98, bottom=0.45 / (height * nrows), top=top,
                        hspace=0.35, wspace=0.22)
    return fig, axes


# A run this long draws its fast signals (a joint dithering by an encoder count) as a solid band
# on its whole time axis: each panel also shows its last ZOOM_S, enlarged (issue 19, item 8).
LONG_RUN_S = 20.0
ZOOM_S = 1.0


def _zoom_end(axes, t_end):
    """An inset of each panel's last ZOOM_S of a long run, redrawn from the panel's own lines
    (panels that have an inset already keep theirs)."""
    if t_end < LONG_RUN_S:
        return
    t0 = t_end - ZOOM_S
    for ax in np.ravel(axes):
        lines = [l for l in ax.get_lines() if len(l.get_xdata()) > 2]      # not the rails (axhline)
        if not lines or ax.child_axes:
            continue
        ins = ax.inset_axes([0.64, 0.55, 0.35, 0.43])
        for line in lines:
            t, y = np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)
            sel = t >= t0
            ins.plot(t[sel], y[sel], color=line.get_color(), linestyle=line.get_linestyle(),
                     linewidth=min(line.get_linewidth(), 0.9), alpha=line.get_alpha())
        ins.set_xlim(t0, t_end)
        ins.tick_params(labelsize=5, pad=1)
        ins.set_title("last %g s, enlarged" % ZOOM_S, fontsize=5.5, pad=1.5)
        ins.grid(True, linewidth=0.3)
        ins.patch.set_alpha(0.9)


def _t_end(runs):
    return max(run.t_s[-1] for run in runs.values())


def _save(fig, path):
    for ax in fig.axes:
        ax.grid(True, linewidth=0.3)
        ax.tick_params(labelsize=7)
    return _write(fig, path)


def _write(fig, path):
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return os.path.basename(path)


def _state_panels(axes, sc, runs, idx, estimates=False, errors=False, solo=False):
    for p, i in enumerate(idx):
        ax = axes.flat[p]
        _shade(ax, sc, runs)
        for label, run in runs.items():
            st = _style(label, solo)
            if errors:
                if run.xhat is not None:
                    ax.plot(run.t_s, (run.xhat[:, i] - run.x[:, i]) * DISPLAY[i], label=label, **st)
                continue
            ax.plot(run.t_s, run.x[:, i] * DISPLAY[i], label=label, **st)
            if estimates and run.xhat is not None:
                ax.plot(run.t_s, run.xhat[:, i] * DISPLAY[i], color=st["color"], linestyle=":", linewidth=1.2,
                        zorder=st["zorder"], label=label + " estimate")
        ax.set_ylabel(STATE_LABELS[i], fontsize=8)
        ax.set_title("(%s)" % LETTERS[p], fontsize=8, loc="left")
    _figure_legend(axes.flat[0].figure, axes.flat[0])


def _xlabel(axes):
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)


def _optimal(runs):
    return {k: v for k, v in runs.items() if k.endswith("/optimal")} or runs


def states_estimates(sc, runs, path):
    fig, axes = _grid(5, 2, caption(sc.name, "states_estimates"))
    # Column-major like the paper: positions left (a-e), rates right (f-j).
    _state_panels(axes.T, sc, runs, range(10), estimates=True)
    _zoom_end(axes, _t_end(runs))
    _xlabel(axes)
    return _save(fig, path)


def transient_window_s(runs, ts_s, fraction=0.01, min_ticks=10):
    """How long the ideal-measurement runs' estimation error takes to fall below `fraction`
    of its start (times 1.5, at least min_ticks); None if it never does or has no start."""
    ends = []
    for label, run in runs.items():
        if label.startswith("firmware/") or run.xhat is None:
            continue
        e = np.max(np.abs(run.xhat - run.x), axis=1)
        if not np.isfinite(e).all() or e[0] == 0:
            continue
        above = np.nonzero(e > fraction * e[0])[0]
        if above[-1] == len(e) - 1:
            return None
        ends.append(run.t_s[above[-1] + 1])
    if not ends:
        return None
    return max(1.5 * max(ends), min_ticks * ts_s)



def estimation_errors(sc, runs, path):
    fig, axes = _grid(5, 2, caption(sc.name, "estimation_errors"))
    _state_panels(axes.T, sc, runs, range(10), errors=True)
    t_end = next(iter(runs.values())).t_s[-1]
    ts_s = np.diff(next(iter(runs.values())).t_s[:2])[0]
    window = transient_window_s(runs, ts_s)
    if window is not None and window < 0.05 * t_end:
        # The detector (poles at 0.2) removes the initial estimation error within a few ticks:
        # on the run's time axis that is one pixel, so the start is drawn again, enlarged.
        for p, i in enumerate(range(10)):
            _inset_start(axes.T.flat[p], runs, i, window)
    _xlabel(axes)
    return _save(fig, path)


def _inset_start(ax, runs, i, window_s):
    ins = ax.inset_axes([0.62, 0.52, 0.36, 0.44])
    for label, run in runs.items():
        if run.xhat is None:
            continue
        sel = run.t_s <= window_s
        st = _style(label)
        ins.plot(run.t_s[sel], (run.xhat[sel, i] - run.x[sel, i]) * DISPLAY[i], marker=".", markersize=3,
                 color=st["color"], linewidth=min(st["linewidth"], 1.5), alpha=st["alpha"], zorder=st["zorder"])
    ins.set_xlim(0, window_s)
    ins.tick_params(labelsize=5.5, pad=1)
    ins.set_title("first %.0f ms" % (window_s * 1e3), fontsize=6, pad=1.5)
    ins.grid(True, linewidth=0.3)


def _inset_demand(ax, runs, i, u_max_v, ts_s):
    """The start of the run at full scale, where the demand goes beyond the main axis."""
    peaks = [(np.nanmax(np.abs(_demand(r, i))), label, r) for label, r in runs.items() if _demand(r, i) is not None]
    peak, label, run = max(peaks, key=lambda c: c[0])
    u = _demand(run, i)
    k = int(np.nanargmax(np.abs(u)))
    # the demand's first excursion beyond the rails, with room after it (at least 20 ticks)
    beyond = np.nonzero(np.abs(np.nan_to_num(u)) > u_max_v)[0]
    beyond = beyond[run.t_s[beyond] <= 0.1 * run.t_s[-1]]
    end = run.t_s[beyond[-1]] if len(beyond) else run.t_s[k]
    window = min(max(20 * ts_s, 1.5 * end, 2 * run.t_s[k]), 0.25 * run.t_s[-1])
    ins = ax.inset_axes([0.60, 0.08, 0.38, 0.84])
    for lab, r in runs.items():
        sel = r.t_s <= window
        st = _style(lab)
        ins.plot(r.t_s[sel], r.u[sel, i], color=st["color"], linewidth=min(st["linewidth"], 1.5),
                 alpha=st["alpha"], zorder=st["zorder"])
        if _demand(r, i) is not None:
            ins.plot(r.t_s[sel], _demand(r, i)[sel], color=st["color"], linestyle=":", marker=".",
                     markersize=2.5, linewidth=0.7, zorder=st["zorder"] - 0.5)
    for s in (-1, 1):
        ins.axhline(s * u_max_v, color="k", linewidth=0.5, linestyle="-.")
    ins.set_xlim(0, window)
    ins.annotate("%.1f V" % u[k], (run.t_s[k], u[k]), xytext=(8, -4 if u[k] > 0 else 4),
                 textcoords="offset points", fontsize=6, color=_style(label)["color"])
    ins.tick_params(labelsize=5.5, pad=1)
    ins.set_title("first %.0f ms, full scale" % (window * 1e3), fontsize=6, pad=1.5)
    ins.grid(True, linewidth=0.3)
    ax.annotate("", (run.t_s[k], ax.get_ylim()[1 if u[k] > 0 else 0]), xytext=(0, -14 if u[k] > 0 else 14),
                textcoords="offset points", arrowprops=dict(arrowstyle="->", linewidth=0.8))


def positions(sc, runs, path):
    fig, axes = _grid(5, 1, caption(sc.name, "positions"))
    _state_panels(axes, sc, runs, range(5))
    _zoom_end(axes, _t_end(runs))
    _xlabel(axes)
    return _save(fig, path)


def velocities(sc, runs, path):
    fig, axes = _grid(5, 1, caption(sc.name, "velocities"))
    _state_panels(axes, sc, runs, range(5, 10))
    _zoom_end(axes, _t_end(runs))
    _xlabel(axes)
    return _save(fig, path)


# The input axes show the rails with this much room; a demand beyond gets an inset.
INPUT_AXIS_RAILS = 2.5


def _demand(run, i):
    u = run.u_unsat
    return None if u is None or not np.isfinite(u[:, i]).any() else u[:, i]


def _cut(run, i, u_max_v):
    """The demand where saturation cut it: beyond +-u_max_v (NaN elsewhere, where the input's line
    shows it: a firmware's input differs from its demand by a duty's rounding and the battery's
    drift, not by saturation), or None without a demand or a cut."""
    d = _demand(run, i)
    if d is None:
        return None
    cut = np.abs(d) > u_max_v
    return np.where(cut, d, np.nan) if cut.any() else None


def inputs(sc, runs, u_max_v, path):
    fig, axes = _grid(4, 1, caption(sc.name, "inputs"))
    ts_s = np.diff(next(iter(runs.values())).t_s[:2])[0]
    any_cut = False
    for p, (i, name) in enumerate(INPUT_LABELS):
        ax = axes.flat[p]
        _shade(ax, sc, runs)
        for label, run in runs.items():
            st = _style(label)
            ax.plot(run.t_s, run.u[:, i], label=label, **st)
            cut = _cut(run, i, u_max_v)
            if cut is not None:
                any_cut = True
                ax.plot(run.t_s, cut, color=st["color"], linestyle=":", linewidth=0.9,
                        alpha=0.8, zorder=st["zorder"] - 0.5)
        for s in (-1, 1):
            ax.axhline(s * u_max_v, color="k", linewidth=0.6, linestyle="-.")
        limit = 1.05 * INPUT_AXIS_RAILS * u_max_v
        peak = max([np.nanmax(np.abs(_demand(r, i))) for r in runs.values() if _demand(r, i) is not None] or [0.0])
        shown = max(1.15 * min(peak, limit), 1.15 * np.max([np.abs(r.u[:, i]).max() for r in runs.values()]), 0.5)
        ax.set_ylim(-shown, shown)
        if peak > shown:
            _inset_demand(ax, runs, i, u_max_v, ts_s)
        ax.set_ylabel(name, fontsize=8)
        ax.set_title("(%s)" % LETTERS[p], fontsize=8, loc="left")
    _zoom_end(axes, _t_end(runs))
    _figure_legend(fig, axes.flat[0])
    axes.flat[-1].set_xlabel("t [s]", fontsize=8)
    if not any_cut:     # the caption's dotted line: say why there is none
        axes.flat[0].set_title("(a)   no input saturated: no dotted line", fontsize=8, loc="left")
    return _save(fig, path)


def _figure_legend(fig, ax):
    """The runs' legend under the title, where no panel's data or inset is."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 1.0 - 0.42 / fig.get_figheight()),
                   ncol=len(handles), fontsize=7, frameon=False)


def compare_controllers(sc, runs, mode, u_max_v, path):
    """Optimal against PD, states and inputs, one mode (as Figure A1)."""
    pair = {k: v for k, v in runs.items() if k.startswith(mode + "/")}
    fig, axes = _grid(7, 2, caption(sc.name, "compare_" + mode), height=1.8)
    _state_panels(axes[:5].T, sc, pair, range(10), solo=True)
    for p, (i, name) in enumerate(INPUT_LABELS):
        ax = axes[5 + p // 2, p % 2]
        _shade(ax, sc, pair)
        for label, run in pair.items():
            ax.plot(run.t_s, run.u[:, i], label=label, **_style(label, solo=True))
        for s in (-1, 1):
            ax.axhline(s * u_max_v, color="k", linewidth=0.6, linestyle="-.")
        ax.set_ylabel(name, fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    return _save(fig, path)


def scenario_plots(sc, runs, u_max_v, out_dir):
    """All figures of a scenario; -> {figure name: file name}."""
    opt = _optimal(runs)
    out = {
        "states_estimates": states_estimates(sc, opt, os.path.join(out_dir, "states_estimates.png")),
        "estimation_errors": estimation_errors(sc, opt, os.path.join(out_dir, "estimation_errors.png")),
        "positions": positions(sc, opt, os.path.join(out_dir, "positions.png")),
        "velocities": velocities(sc, opt, os.path.join(out_dir, "velocities.png")),
        "inputs": inputs(sc, opt, u_max_v, os.path.join(out_dir, "inputs.png")),
    }
    if sc.course:
        out["plan_view"] = plan_view(sc, opt, os.path.join(out_dir, "plan_view.png"))
    if len(sc.controllers) > 1:
        for mode in sorted({label.split("/")[0] for label in runs}):
            out["compare_" + mode] = compare_controllers(sc, runs, mode, u_max_v,
                                                         os.path.join(out_dir, "compare_%s.png" % mode))
    return out


def plan_view(sc, runs, path):
    """Driving: the commanded path and the simulated robot's true path seen from above."""
    from hostsim.model.params import scaled_params
    from hostsim.sim import tracking
    fig, ax = plt.subplots(figsize=(6.5, 6.0))
    fig.suptitle(caption(sc.name, "plan view: commanded (dashed) and true path; o start, x end"), fontsize=10)
    track_m = scaled_params(sc.param_scale)["track_m"]
    segments = [(v, np.degrees(w), d) for v, w, d in sc.course]
    for label, run in runs.items():
        true = tracking.planar_path(run.t_s, run.x[:, 0], run.x[:, 1], track_m)
        commanded = tracking.commanded_path(segments, 0.0, end_s=float(run.t_s[-1]))
        tracking.plan_view_plot(ax, true, commanded, label=label)
    return _save(fig, path)


def montecarlo_figure(results, path, what="parameter, sensor and timing uncertainty"):
    """Distributions of peak tilt and peak voltage per gains file, successes and failures."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.8))
    # one set of bins for every gains file's histogram: overlaid, their bars compare
    every = [r for res in results.values() for r in res["runs"]]
    tilt_bins = np.histogram_bin_edges([r["peak_abs_th1_rad"] for r in every], bins=30)
    volt_bins = np.histogram_bin_edges([r["peak_abs_u_v"] for r in every], bins=30)
    for i, (name, res) in enumerate(results.items()):
        color = "C%d" % i
        rows = res["runs"]
        ok = np.array([r["success"] for r in rows])
        tilt = np.array([r["peak_abs_th1_rad"] for r in rows])
        volt = np.array([r["peak_abs_u_v"] for r in rows])
        axes[0].hist(tilt, bins=tilt_bins, alpha=0.5, color=color, label="%s (%.0f %% ok)" % (name, 100 * ok.mean()))
        axes[1].hist(volt, bins=volt_bins, alpha=0.5, color=color, label=name)
        if ok.any():
            axes[2].scatter(tilt[ok], volt[ok], s=8, color=color, label=name + " ok")
        if (~ok).any():
            axes[2].scatter(tilt[~ok], volt[~ok], s=16, marker="x", color=color, label=name + " failed")
    axes[0].set_xlabel("peak |th1| of a run [rad]")
    axes[1].set_xlabel("peak |u| of a run [V]")
    for ax, title in zip(axes[:2], ("peak tilt", "peak input")):
        ax.set_ylabel("runs")
        ax.set_title(title, fontsize=9)
    axes[2].set_xlabel("peak |th1| [rad]")
    axes[2].set_ylabel("peak |u| [V]")
    axes[2].set_title("each run", fontsize=9)
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(True, linewidth=0.3)
    fig.suptitle("Monte Carlo: firmware in the loop, %s" % what, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return _write(fig, path)


def margins_figure(res, path, margins):
    """One panel per effect of ``margins`` (hostsim.studies.margins.MARGINS): the largest value
    each gains file balances with (each sign where there are two; a triangle: at least that, the
    search's end), the realistic brick's dashed."""
    labels = sorted({r["gains"] for r in res["margins"]})
    ncols = min(5, len(margins))             # rows of five panels: readable at the report's width
    nrows = -(-len(margins) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.4 * ncols, 3.0 * nrows + 0.6), squeeze=False)
    for ax in axes.flat[len(margins):]:
        ax.set_visible(False)
    for ax, m in zip(axes.flat, margins):
        names, values, beyond = [], [], []
        for label in labels:
            for r in sorted((r for r in res["margins"] if r["gains"] == label and r["effect"] == m.key),
                            key=lambda r: -r["sign"]):
                names.append(label + ("" if len(m.signs) == 1 else (" +" if r["sign"] > 0 else " -")))
                values.append(0.0 if r["margin"] is None else r["margin"])
                beyond.append(r["at_least"])
        x = np.arange(len(values))
        ax.bar(x, values, color=["C%d" % labels.index(n.split(" ")[0]) for n in names])
        for xi, v, b in zip(x, values, beyond):
            # three significant digits, as the table: a bisection's points (32.8125) claim more than its tolerance
            ax.annotate("%.3g" % v, (xi, v), ha="center", va="bottom", fontsize=6)
            if b:
                ax.plot(xi, v, marker="^", color="k", markersize=5)
        if m.realistic_value is not None:
            ax.axhline(m.realistic_value, color="k", linestyle="--", linewidth=0.8)
        ax.set_ylim(0, 1.15 * max(values + [m.realistic_value or 0.0]) or 1.0)
        ax.set_xticks(x)
        ax.set_xticklabels(names, rotation=45, ha="right", fontsize=7)
        ax.set_title("%s [%s]" % (m.label, m.unit), fontsize=8)
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(True, axis="y", linewidth=0.3)
    fig.suptitle("Largest value of each effect alone at which the robot still balances %g s "
                 "(bars; triangle: at least that, the search's upper end; dashed: the realistic brick)"
                 % res["_meta"]["duration_s"], fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.25 / (3.0 * nrows + 0.6)))
    return _write(fig, path)


def roa_figure(table, path):
    """Bar chart: largest recovered initial angle per gains file, angle, sign and mode."""
    keys = sorted({(r["angle"], r["sign"]) for r in table})
    groups = sorted({(r["gains"], r["mode"]) for r in table})
    fig, ax = plt.subplots(figsize=(10, 3.8))
    width = 0.8 / max(1, len(groups))
    for gi, group in enumerate(groups):
        vals, at_limit = [], []
        for key in keys:
            hit = [r for r in table if (r["gains"], r["mode"]) == group and (r["angle"], r["sign"]) == key]
            vals.append(hit[0]["max_recovered_rad"] if hit else 0.0)
            at_limit.append(bool(hit) and hit[0]["max_recovered_rad"] >= hit[0]["limit_rad"])
        x = np.arange(len(keys)) + gi * width
        bars = ax.bar(x, vals, width, label="%s gains, %s" % group)
        # A bar at the firmware's stop limit is where the search stopped, not where recovery ends.
        for xi, v, lim, bar in zip(x, vals, at_limit, bars):
            if lim:
                bar.set_hatch("///")
                ax.plot(xi, v, marker="v", color="k", markersize=5, zorder=5)
    limits = {}
    for r in table:
        limits[(r["angle"], r["sign"])] = r["limit_rad"]
    for k, key in enumerate(keys):
        ax.hlines(limits[key], k - width / 2, k + 0.8 - width / 2, colors="k", linestyles=":", linewidth=0.8)
    ax.plot([], [], marker="v", color="k", linestyle=":", linewidth=0.8,
            label="firmware stop limit (hatched bar: recovered up to it)")
    ax.set_xticks(np.arange(len(keys)) + 0.4 - width / 2)
    ax.set_xticklabels(["%s%s" % (("+" if s > 0 else "-"), a) for a, s in keys])
    ax.set_ylabel("largest recovered initial angle [rad]")
    ax.set_xlabel("initial angle (only that one nonzero, released from rest)")
    ax.set_ylim(0, 1.3 * max(limits.values()))        # room for the legend above the bars
    ax.legend(fontsize=7, loc="upper left", ncol=2)
    ax.grid(True, axis="y", linewidth=0.3)
    fig.tight_layout()
    return _write(fig, path)
