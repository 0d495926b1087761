"""PNG figures laid out like the paper's (matplotlib, Agg backend; no display needed).

- ``states_estimates.png``: Figure 5, each state against its estimate (10 panels a-j);
- ``estimation_errors.png``: Figure 6, x~ - x;
- ``positions.png``, ``velocities.png``, ``inputs.png``: Figures 8, 9 and 10 (the paper
  draws its simulation in red and its experiment in blue: here the linear run is red and
  the firmware-in-the-loop run blue, the nonlinear ideal-measurement run green);
- ``compare_<mode>.png``: Figure A1, optimal against PD;
- robustness figures for the Monte Carlo and the region of attraction.

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
LETTERS = "abcdefghij"


MODE_WIDTH = {"linear": 1.8, "nonlinear": 0.9, "firmware": 1.0}
# The firmware run (noisy) underneath, the nonlinear one on top of the wider linear one.
MODE_ZORDER = {"linear": 3, "nonlinear": 4, "firmware": 2}


def _style(label):
    mode, controller = label.split("/")
    return dict(color=MODE_COLORS.get(mode, "k"), linestyle=CONTROLLER_STYLE.get(controller, "-"),
                linewidth=MODE_WIDTH.get(mode, 1.0), zorder=MODE_ZORDER.get(mode, 2))


def _shade(ax, sc):
    end = sc.duration_s
    for d in sc.disturbances:
        if any(d.w_v) and d.t_start_s < end:
            ax.axvspan(d.t_start_s, min(d.t_end_s, end), color="0.88", zorder=0)
    ax.set_xlim(0.0, end)


def _grid(nrows, ncols, title, height=2.0):
    fig, axes = plt.subplots(nrows, ncols, figsize=(6.0 * ncols, height * nrows), sharex=True, squeeze=False)
    fig.suptitle(title, fontsize=11)
    # Fixed margins: tight_layout costs more than drawing these figures.
    top = 1.0 - 0.8 / (height * nrows)
    fig.subplots_adjust(left=0.09 / ncols + 0.03, right=0.98, bottom=0.45 / (height * nrows), top=top,
                        hspace=0.35, wspace=0.22)
    return fig, axes


def _save(fig, path):
    for ax in fig.axes:
        ax.grid(True, linewidth=0.3)
        ax.tick_params(labelsize=7)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return os.path.basename(path)


def _state_panels(axes, sc, runs, idx, estimates=False, errors=False):
    for p, i in enumerate(idx):
        ax = axes.flat[p]
        _shade(ax, sc)
        for label, run in runs.items():
            st = _style(label)
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
    if axes.flat[0].get_legend_handles_labels()[0]:
        axes.flat[0].legend(fontsize=6, loc="best")


def _xlabel(axes):
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)


def _optimal(runs):
    return {k: v for k, v in runs.items() if k.endswith("/optimal")} or runs


def states_estimates(sc, runs, path):
    fig, axes = _grid(5, 2, "%s: states (solid) and estimates (dotted), cf. paper Figure 5" % sc.name)
    # Column-major like the paper: positions left (a-e), rates right (f-j).
    _state_panels(axes.T, sc, runs, range(10), estimates=True)
    _xlabel(axes)
    return _save(fig, path)


def estimation_errors(sc, runs, path):
    fig, axes = _grid(5, 2, "%s: estimation errors x~ - x, cf. paper Figure 6" % sc.name)
    _state_panels(axes.T, sc, runs, range(10), errors=True)
    _xlabel(axes)
    return _save(fig, path)


def positions(sc, runs, path):
    fig, axes = _grid(5, 1, "%s: positions, cf. paper Figure 8" % sc.name)
    _state_panels(axes, sc, runs, range(5))
    _xlabel(axes)
    return _save(fig, path)


def velocities(sc, runs, path):
    fig, axes = _grid(5, 1, "%s: velocities, cf. paper Figure 9" % sc.name)
    _state_panels(axes, sc, runs, range(5, 10))
    _xlabel(axes)
    return _save(fig, path)


def inputs(sc, runs, u_max_v, path):
    fig, axes = _grid(4, 1, "%s: control inputs, cf. paper Figure 10 (dashed: before saturation)" % sc.name)
    for p, (i, name) in enumerate(INPUT_LABELS):
        ax = axes.flat[p]
        _shade(ax, sc)
        for label, run in runs.items():
            st = _style(label)
            ax.plot(run.t_s, run.u[:, i], label=label, **st)
            if run.u_unsat is not None:
                unsat = np.clip(run.u_unsat[:, i], -3 * u_max_v, 3 * u_max_v)
                ax.plot(run.t_s, unsat, color=st["color"], linestyle="--", linewidth=0.6, alpha=0.6,
                        zorder=st["zorder"] - 0.5)
        for s in (-1, 1):
            ax.axhline(s * u_max_v, color="k", linewidth=0.6, linestyle="-.")
        ax.set_ylabel(name, fontsize=8)
        ax.set_title("(%s)" % LETTERS[p], fontsize=8, loc="left")
    axes.flat[0].legend(fontsize=6)
    axes.flat[-1].set_xlabel("t [s]", fontsize=8)
    return _save(fig, path)


def compare_controllers(sc, runs, mode, u_max_v, path):
    """Figure A1: optimal against PD, states and inputs, one mode."""
    pair = {k: v for k, v in runs.items() if k.startswith(mode + "/")}
    fig, axes = _grid(7, 2, "%s (%s): optimal controller (solid) vs PD (dashed), cf. paper Figure A1"
                      % (sc.name, mode), height=1.8)
    _state_panels(axes[:5].T, sc, pair, range(10))
    for p, (i, name) in enumerate(INPUT_LABELS):
        ax = axes[5 + p // 2, p % 2]
        _shade(ax, sc)
        for label, run in pair.items():
            ax.plot(run.t_s, run.u[:, i], label=label, **_style(label))
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
    if len(sc.controllers) > 1:
        for mode in sorted({label.split("/")[0] for label in runs}):
            out["compare_" + mode] = compare_controllers(sc, runs, mode, u_max_v,
                                                         os.path.join(out_dir, "compare_%s.png" % mode))
    return out


def montecarlo_figure(results, path):
    """Distributions of peak tilt and peak voltage per gains file, successes and failures."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.8))
    for i, (name, res) in enumerate(results.items()):
        color = "C%d" % i
        rows = res["runs"]
        ok = np.array([r["success"] for r in rows])
        tilt = np.array([r["peak_abs_th1_rad"] for r in rows])
        volt = np.array([r["peak_abs_u_v"] for r in rows])
        axes[0].hist(tilt, bins=30, alpha=0.5, color=color, label="%s (%.0f %% ok)" % (name, 100 * ok.mean()))
        axes[1].hist(volt, bins=30, alpha=0.5, color=color, label=name)
        if ok.any():
            axes[2].scatter(tilt[ok], volt[ok], s=8, color=color, label=name + " ok")
        if (~ok).any():
            axes[2].scatter(tilt[~ok], volt[~ok], s=16, marker="x", color=color, label=name + " failed")
    axes[0].set_xlabel("peak |th1| [rad]")
    axes[1].set_xlabel("peak |u| [V]")
    axes[2].set_xlabel("peak |th1| [rad]")
    axes[2].set_ylabel("peak |u| [V]")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(True, linewidth=0.3)
    fig.suptitle("Monte Carlo: firmware in the loop under parameter, sensor and timing uncertainty", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return os.path.basename(path)


def roa_figure(table, path):
    """Bar chart: largest recovered initial angle per gains file, angle, sign and mode."""
    keys = sorted({(r["angle"], r["sign"]) for r in table})
    groups = sorted({(r["gains"], r["mode"]) for r in table})
    fig, ax = plt.subplots(figsize=(10, 3.8))
    width = 0.8 / max(1, len(groups))
    for gi, group in enumerate(groups):
        vals = []
        for key in keys:
            hit = [r["max_recovered_rad"] for r in table if (r["gains"], r["mode"]) == group and (r["angle"], r["sign"]) == key]
            vals.append(hit[0] if hit else 0.0)
        ax.bar(np.arange(len(keys)) + gi * width, vals, width, label="%s gains, %s" % group)
    ax.set_xticks(np.arange(len(keys)) + 0.4 - width / 2)
    ax.set_xticklabels(["%s%s" % (("+" if s > 0 else "-"), a) for a, s in keys])
    ax.set_ylabel("largest recovered initial angle [rad]")
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", linewidth=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return os.path.basename(path)
