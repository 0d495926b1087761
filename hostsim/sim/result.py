"""What a simulated run returns: one record, whichever simulator ran it (SI units).

hostsim.sim.linear_sim (linear and nonlinear modes) and hostsim.sim.firmware_run (the firmware in the
loop) fill the fields they know; the others stay None. Arrays have one row per control tick,
row k at t_s[k] (t = 0: the release).
"""
import dataclasses
from typing import Any, Optional

import numpy as np


@dataclasses.dataclass(frozen=True)
class RunResult:
    t_s: np.ndarray                      # tick times (s)
    x: np.ndarray                        # plant state at the ticks (n x 10)
    u: np.ndarray                        # the inputs the plant got over each tick (n x 5, V)
    w: np.ndarray                        # the disturbance added to them (n x 5, V)
    completed: bool                      # ran the scenario's duration (no fall, no safety stop)
    # Where the controller's wheel origin lies in the scenario's frame (m): 0, or per wheel.
    d_origin_m: Any = 0.0
    xhat: Optional[np.ndarray] = None    # the controller's estimate (x~, or the firmware's x^: n x 10)
    w_hat: Optional[np.ndarray] = None   # its disturbance estimate (n x 5, V)
    u_unsat: Optional[np.ndarray] = None  # the law's output before saturation (n x 5, V)
    # The firmware in the loop only:
    u_applied: Optional[np.ndarray] = None   # the inputs it applied (n x 5, V)
    exit_code: Optional[int] = None
    stop_reason: Optional[str] = None
    header: Optional[dict] = None        # its log's header
    flags: Optional[np.ndarray] = None   # its log's flag bits per tick (tipbot_fw.record.logfile.FLAG_BITS)
    tick_work_s: Optional[np.ndarray] = None  # its log's tick_s: a tick's start to the end of its writes
    io_per_iteration: Optional[list] = None  # sysfs runs: the device layer's (op, path, bytes) per loop
    duty_events: Optional[list] = None   # brick worlds: (t from release, motor, duty fraction) applied
    wall_s: Optional[float] = None       # the simulation's own wall time

    def arrays(self):
        """{field: array} of the fields that are arrays (what runs.npz keeps)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}
