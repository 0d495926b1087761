"""Reading a firmware-in-the-loop run back (hostsim.sim.firmware_run): what the plant did, from
the world's records, and what the firmware saw and did, from its log, the one place the host
reads a run's log (tipbot_fw.record.replay.signals, for either core; flags and tick time by
column name) -> the RunResult.
"""
import dataclasses

import numpy as np

from hostsim.sim.firmware_build import SimulationError
from hostsim.sim.result import RunResult
from tipbot_fw.record import logfile
from tipbot_fw.record import replay as fw_replay


@dataclasses.dataclass(frozen=True)
class WorldSide:
    """What the plant did, at the ticks: t_s (from the release), x (SI), u (the motors' volts
    over each tick), w (the disturbance added to them)."""
    t_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    w: np.ndarray


@dataclasses.dataclass(frozen=True)
class FirmwareSide:
    """What the firmware saw and did, tick k <-> plant sample k (NaN for the ticks a long run's
    bounded log did not keep, and after its last row): its estimate in the scenario's frame,
    the disturbance estimate, the inputs it applied, its law's output before saturation, the
    flags and each tick's work time."""
    xhat: np.ndarray
    w_hat: np.ndarray
    u_applied: np.ndarray
    u_unsat: np.ndarray
    flags: np.ndarray
    tick_work_s: np.ndarray


def world_side(world):
    """What the plant did (WorldSide)."""
    n = len(world.log_t)
    u = np.zeros((n, 5))
    w = np.zeros((n, 5))
    m = len(world.log_u)
    if m:
        # log_u[k] is what the plant got over tick k; the last tick has none: repeat.
        u[:m], w[:m] = world.log_u[:n], world.log_w[:n]
        u[m:], w[m:] = world.log_u[-1], world.log_w[-1]
    return WorldSide(t_s=np.array(world.log_t), x=np.array(world.log_x).reshape(n, 10), u=u, w=w)


def firmware_side(header, rows, gains, d_origin, n):
    """The firmware's own view from its log (FirmwareSide) for n plant samples."""
    ticks = logfile.tick_indices(header, len(rows))
    dense = np.full((min(n, int(ticks[-1]) + 1 if len(ticks) else 0), rows.shape[1]), np.nan)
    dense[ticks[ticks < len(dense)]] = rows[ticks < len(dense)]
    rows = dense
    sig = fw_replay.signals(header, rows[:n], gains)
    shift = np.zeros(10)
    shift[:2] = d_origin
    xhat = sig.x_hat + shift
    # replay.signals: u the inputs applied, u_cmd the law's output before saturation
    w_hat, u_applied, u_unsat = sig.w_hat, sig.u, sig.u_cmd
    names = [c["name"] for c in header["columns"]]
    flags, tick = (rows[:n, names.index(c)][:, None] for c in ("flags", "tick_s"))
    if len(xhat) < n:
        pad = n - len(xhat)
        xhat, w_hat, u_applied, u_unsat, flags, tick = (np.vstack([a, np.full((pad, a.shape[1]), np.nan)])
                                                        for a in (xhat, w_hat, u_applied, u_unsat, flags, tick))
    return FirmwareSide(xhat=xhat, w_hat=w_hat, u_applied=u_applied, u_unsat=u_unsat, flags=flags[:, 0],
                        tick_work_s=tick[:, 0])


def wheel_origin(sc, config):
    """d_origin_m: the plant's wheel positions where the firmware counts its zero from (it counts
    from R_w times the tilt it is told: hostsim.sim.firmware_run's module docstring)."""
    rw = config["wheel_radius_m"]
    th1_told = config["start_pose_rad"]["th1"]
    return np.array([sc.x0_si[0] - rw * th1_told, sc.x0_si[1] - rw * th1_told])


def check_timing(world, header, ts_s):
    """The world let the robot go where the session says its calibration ended and its loop
    started (the run's header: its ``timing``): no earlier than the last calibration sample, no
    later than the loop's first tick. SimulationError otherwise (the lock-step is broken)."""
    timing = header.get("timing") or {}
    end, loop = timing.get("calibration_end_s"), timing.get("loop_start_s")
    if not world.released or end is None or loop is None:
        return
    if not end - 1e-9 <= world.t_release_s <= loop + ts_s + 1e-9:
        raise SimulationError("the world let go at %.9f s, the firmware calibrated until %.9f s and started its "
                              "loop at %.9f s" % (world.t_release_s, end, loop))


def read_back(run, code, header, log_header=None, rows=None):
    """The RunResult of a finished run (hostsim.sim.firmware_build.FirmwareRun): the world's
    records, and with the firmware's log (its header and rows) the firmware's side."""
    world = run.world
    check_timing(world, header, run.gains.ts_s)
    if not world.released:                      # stopped at its first tick
        world._record(world.t_release_s)
    d_origin = wheel_origin(run.sc, run.config)
    out = dataclasses.asdict(world_side(world))
    if run.fake is not None:
        out["io_per_iteration"] = [run.fake.io.log[a:b] for a, b in zip(world.io_marks, world.io_marks[1:])]
    if rows is not None:
        out.update(dataclasses.asdict(firmware_side(log_header, rows, run.gains, d_origin, len(out["t_s"]))))
    if hasattr(world, "duty_events"):
        out["duty_events"] = world.duty_events
    return RunResult(d_origin_m=d_origin, exit_code=code, stop_reason=header.get("stop_reason"), header=header,
                     completed=code == 0 and header.get("stop_reason") == "completed", **out)
