"""The robot's path in the plane and how well it tracked a commanded course (issue 21).

The plant moves its two wheels (d_r, d_l: rolling displacement, positive forward); its path in
the plane follows from them alone (rolling without slip): the heading turns by the wheels'
difference over the track, the robot moves by their mean along its heading. The commanded path
is the course's segments integrated exactly (arcs, lines, turns in place), without the ramps the
firmware's plan adds: tracking errors include what the ramps cost, as an owner would measure
them with a tape on the floor. Every figure is of the simulated robot's true motion, not of the
firmware's odometry.
"""
import math

import numpy as np


def planar_path(t_s, d_r_m, d_l_m, track_m):
    """{t_s, x_m, y_m, heading_rad, speed_mps, yaw_rate_rad_s} of the wheels' displacements
    (from (0, 0), heading 0 at the first sample; heading positive to the left)."""
    t = np.asarray(t_s, dtype=float)
    dr = np.asarray(d_r_m, dtype=float) - d_r_m[0]
    dl = np.asarray(d_l_m, dtype=float) - d_l_m[0]
    heading = (dr - dl) / track_m
    ds = np.diff(0.5 * (dr + dl))
    mid = 0.5 * (heading[1:] + heading[:-1])
    x = np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))])
    y = np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))])
    if len(t) > 1:
        speed, yaw_rate = np.gradient(0.5 * (dr + dl), t), np.gradient(heading, t)
    else:
        speed, yaw_rate = np.zeros(1), np.zeros(1)
    return {"t_s": t, "x_m": x, "y_m": y, "heading_rad": heading, "speed_mps": speed, "yaw_rate_rad_s": yaw_rate}


def _advance(x, y, h, v, w, dt):
    """The exact pose after dt at speed v and yaw rate w (an arc; a line when w is 0)."""
    if w == 0.0:
        return x + v * dt * math.cos(h), y + v * dt * math.sin(h), h
    h1 = h + w * dt
    r = v / w
    return x + r * (math.sin(h1) - math.sin(h)), y - r * (math.cos(h1) - math.cos(h)), h1


def commanded_path(segments, t0_s, dt_s=0.005, end_s=None):
    """The course [(speed_mps, yaw_rate_dps, duration_s)] from t0_s as the same dict as
    planar_path, sampled every dt_s from 0 (at rest at the origin before t0_s and, after the
    last segment, where it ended, until end_s if given)."""
    starts = [t0_s]
    for _, _, d in segments:
        starts.append(starts[-1] + d)
    stop = starts[-1] if end_s is None else max(end_s, starts[-1])
    t = np.arange(0.0, stop + dt_s / 2, dt_s)
    x, y, h = np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t))
    v, w = np.zeros(len(t)), np.zeros(len(t))
    pose = (0.0, 0.0, 0.0)
    poses = [pose]          # at each segment's start
    for speed, yaw_dps, d in segments:
        pose = _advance(*pose, speed, math.radians(yaw_dps), d)
        poses.append(pose)
    for k, tk in enumerate(t):
        i = int(np.searchsorted(starts, tk, side="right")) - 1
        if i < 0:
            continue
        if i >= len(segments):
            x[k], y[k], h[k] = poses[-1]
            continue
        speed, yaw_dps, _ = segments[i]
        x[k], y[k], h[k] = _advance(*poses[i], speed, math.radians(yaw_dps), tk - starts[i])
        v[k], w[k] = speed, math.radians(yaw_dps)
    return {"t_s": t, "x_m": x, "y_m": y, "heading_rad": h, "speed_mps": v, "yaw_rate_rad_s": w}


def cross_track_m(x_m, y_m, path_x_m, path_y_m, chunk=2000):
    """Each point's distance to the polyline (path_x, path_y); repeated points allowed."""
    px, py = np.asarray(path_x_m, float), np.asarray(path_y_m, float)
    keep = np.concatenate([[True], (np.diff(px) != 0) | (np.diff(py) != 0)])
    px, py = px[keep], py[keep]
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    if len(px) == 1:
        return np.hypot(x - px[0], y - py[0])
    ax, ay, bx, by = px[:-1], py[:-1], px[1:], py[1:]
    ex, ey = bx - ax, by - ay
    len2 = ex * ex + ey * ey
    out = np.empty(len(x))
    for i in range(0, len(x), chunk):
        qx, qy = x[i:i + chunk, None], y[i:i + chunk, None]
        u = np.clip(((qx - ax) * ex + (qy - ay) * ey) / len2, 0.0, 1.0)
        out[i:i + chunk] = np.min(np.hypot(qx - (ax + u * ex), qy - (ay + u * ey)), axis=1)
    return out


def tracking_metrics(true, commanded):
    """The figures of the issue: RMS cross-track error over the course (from the commanded
    path's first motion to its end), final position and heading errors, the true path's
    largest speed and yaw rate."""
    moving = np.nonzero((commanded["speed_mps"] != 0) | (commanded["yaw_rate_rad_s"] != 0))[0]
    t0 = commanded["t_s"][moving[0]] if len(moving) else 0.0
    sel = true["t_s"] >= t0
    ct = cross_track_m(true["x_m"][sel], true["y_m"][sel], commanded["x_m"], commanded["y_m"])
    dh = math.degrees(true["heading_rad"][-1] - commanded["heading_rad"][-1])
    dh = (dh + 180.0) % 360.0 - 180.0
    return {
        "rms_cross_track_m": float(np.sqrt(np.mean(ct ** 2))) if len(ct) else 0.0,
        "final_position_error_m": float(math.hypot(true["x_m"][-1] - commanded["x_m"][-1],
                                                   true["y_m"][-1] - commanded["y_m"][-1])),
        "final_heading_error_deg": abs(dh),
        "max_speed_mps": float(np.max(np.abs(true["speed_mps"]))),
        "max_yaw_rate_dps": float(math.degrees(np.max(np.abs(true["yaw_rate_rad_s"])))),
    }


def plan_view_plot(ax, true, commanded, label=None):
    """The commanded path (dashed) and the true one (solid) in the plane, start o, end x."""
    ax.plot(commanded["x_m"], commanded["y_m"], "k--", lw=1.0, label="commanded")
    line, = ax.plot(true["x_m"], true["y_m"], lw=1.4, label=label or "robot (true path)")
    ax.plot(true["x_m"][0], true["y_m"][0], "o", color=line.get_color())
    ax.plot(true["x_m"][-1], true["y_m"][-1], "x", color=line.get_color(), ms=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, alpha=0.3)
