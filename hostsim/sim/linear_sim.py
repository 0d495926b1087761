"""The paper's simulation: the detector and the controller on the linear or nonlinear model.

Linear: plant x_{k+1} = A x_k + B (u_k + w_k) (input disturbances, E = B), full-state
measurement y = x. Nonlinear: the same loop around hostsim.world.plant, the input (plus w) held
over each tick, y = x sampled at the ticks. The detector and the control law are those of
docs/architecture.md, with the same saturation as the firmware. Written independently of
tipbot_fw so that comparing the two tests the firmware's implementation.

Everything here is SI (m, rad, V): the gains are a tipbot_fw.gains.Gains, which the firmware's
own loader validated and converted to SI (a gains file in paper units, cm, included).
"""
import numpy as np

from hostsim.model import design
from hostsim.model.params import scaled_params
from hostsim.model.equations import RobotModel, state_scale_to_si
from hostsim.sim.governor import ReferenceGovernor
from hostsim.sim.result import RunResult
from hostsim.world.plant import Plant, disturbance_at
from hostsim.sim.scenario import scenario_load

PLANT_DT_S = 0.001


def _saturate(u, limit):
    return np.clip(u, -limit, limit)


class HostController:
    """Detector + control law of docs/architecture.md (SI), one tick at a time.

    With ``k_pd`` (5x10, SI) the law is the PD baseline u = -K_pd y (no K_w); the detector
    still runs, so its estimates can be compared. With ``governor`` (hostsim.sim.governor) the
    law acts around the governor's reference: u = u_r - K (x~ - x_r) - K_w w^.
    """

    def __init__(self, g, xhat0, y0, k_pd=None, governor=None):
        self.g = g
        self.k_pd = k_pd
        self.governor = governor
        self.ref, self.u_ref = np.zeros(10), np.zeros(5)
        self.xh = np.array(xhat0, dtype=float)
        if governor is not None:
            self.ref, self.u_ref = governor.reference(self.xh)
        self.y = np.array(y0, dtype=float)
        self.w_hat = np.zeros(5)
        self.u_unsat = self._law(self.xh, self.y, self.w_hat)
        self.u = _saturate(self.u_unsat, g.u_max_v)
        self._ca, self._cb = g.C @ g.A, g.C @ g.B

    def _law(self, xh, y, w_hat):
        if self.k_pd is not None:
            return -self.k_pd @ y
        return self.u_ref - self.g.K @ (xh - self.ref) - self.g.K_w @ w_hat

    def update(self, y_next):
        """Read y_{k+1}: update the estimate and w^, return u_{k+1} (saturated)."""
        g = self.g
        # The detector is fed the input the controller applied (saturated, before any delay).
        nu = y_next - self._ca @ self.xh - self._cb @ self.u
        self.w_hat = g.G_w @ nu
        self.xh = g.A @ self.xh + g.B @ self.u + g.L1 @ (self.y - g.C @ self.xh) + g.L2 @ nu
        self.y = np.array(y_next, dtype=float)
        if self.governor is not None:
            self.ref, self.u_ref = self.governor.reference(self.xh)
        self.u_unsat = self._law(self.xh, self.y, self.w_hat)
        self.u = _saturate(self.u_unsat, g.u_max_v)
        return self.u


class IdealController:
    """The perfect-measurement reference: u_k = sat(-K x_k - K_w w_k) with the TRUE state and
    disturbance (no sensor, no estimator, no delay). The firmware's inputs are judged against
    this run's (metrics rms_u_ratio_to_ideal)."""

    def __init__(self, g, sc, x0):
        self.g, self.sc, self.k = g, sc, 0
        self.w_hat = np.zeros(5)
        self._set(np.asarray(x0, dtype=float))

    def _set(self, x):
        self.xh = x
        self.w_hat = np.array(disturbance_at(self.sc, self.k * self.g.ts_s))
        self.u_unsat = -self.g.K @ x - self.g.K_w @ self.w_hat
        self.u = _saturate(self.u_unsat, self.g.u_max_v)

    def update(self, x_next):
        self.k += 1
        self._set(np.array(x_next, dtype=float))
        return self.u


def truth_linear_model(g, sc, params=None):
    """(A, B) in SI of the plant a linear run simulates.

    The gains' own model when the scenario's plant is that model unperturbed (so Section 7
    runs on exactly the paper's matrices), else the linearization of the scenario's plant.
    """
    if sc.plant_variant == g.model_variant and not sc.param_scale:
        return g.A, g.B
    return design.discrete_model_si(RobotModel(sc.plant_variant, scaled_params(sc.param_scale, params)),
                                    g.ts_s)


class _Recorder:
    def __init__(self, n):
        self.t = np.zeros(n + 1)
        self.x = np.zeros((n + 1, 10))
        self.xhat = np.zeros((n + 1, 10))
        self.u = np.zeros((n + 1, 5))
        self.u_unsat = np.zeros((n + 1, 5))
        self.w = np.zeros((n + 1, 5))
        self.w_hat = np.zeros((n + 1, 5))

    def put(self, k, t, x, ctl, w):
        self.t[k], self.x[k], self.xhat[k], self.w[k] = t, x, ctl.xh, w
        self.u[k], self.u_unsat[k], self.w_hat[k] = ctl.u, ctl.u_unsat, ctl.w_hat

    def result(self, n, completed):
        return RunResult(t_s=self.t[:n], x=self.x[:n], xhat=self.xhat[:n], u=self.u[:n], u_unsat=self.u_unsat[:n],
                         w=self.w[:n], w_hat=self.w_hat[:n], completed=completed)


def _simulate(g, sc, k_pd, x0, step, fallen, ideal=False):
    n_steps = int(round(sc.duration_s / g.ts_s))
    xhat0 = sc.xhat0_si if sc.xhat0_si is not None else sc.x0_si
    x = np.array(x0, dtype=float)
    governor = ReferenceGovernor(g, xhat0) if sc.reference_governor and k_pd is None and not ideal else None
    ctl = IdealController(g, sc, x) if ideal else HostController(g, xhat0, g.C @ x, k_pd, governor)
    pending = [np.zeros(5)] * sc.extra_delay_ticks
    rec = _Recorder(n_steps)
    for k in range(n_steps + 1):
        t = k * g.ts_s
        w = np.array(disturbance_at(sc, t))
        rec.put(k, t, x, ctl, w)
        if k == n_steps or fallen(x):
            return rec.result(k + 1, completed=k == n_steps)
        pending.append(ctl.u)
        x = step(x, pending.pop(0) + w, t)
        ctl.update(g.C @ x)


def simulate_linear(g, sc, k_pd=None, params=None):
    """Run a scenario on the linear model -> RunResult (SI)."""
    a, b = truth_linear_model(g, sc, params)
    return _simulate(g, sc, k_pd, sc.x0_si, lambda x, u, t: a @ x + b @ u, lambda x: False)


def simulate_nonlinear(g, sc, k_pd=None, params=None, fall_rad=np.pi / 2, ideal=False):
    """Run a scenario on the nonlinear plant with ideal measurement -> RunResult (SI).

    Stops early (completed=False) when |th1| passes fall_rad: the model means nothing once
    the robot lies on the floor. ideal: the IdealController (true state and disturbance)
    instead of the detector.
    """
    model = RobotModel(sc.plant_variant, scaled_params(sc.param_scale, params))
    to_si = np.diag(state_scale_to_si(model.variant))
    plant = Plant(model, np.array(sc.x0_si) / to_si, dt_s=PLANT_DT_S, method=sc.plant_method)
    plant.load = scenario_load(sc, model, plant.x)
    pushes = sorted((p.t_s, p.th1_dot_rad_s) for p in sc.pushes)

    def step(x, u, t):
        t_end = t + g.ts_s
        while pushes and pushes[0][0] < t_end - 1e-12:
            t_push, kick = pushes.pop(0)
            if t_push > t + 1e-12:
                plant.advance(u, t_push - t)
                t = t_push
            plant.x[7] += kick
        plant.advance(u, t_end - t)
        return plant.x_si

    return _simulate(g, sc, k_pd, sc.x0_si, step, lambda x: abs(x[2]) > fall_rad, ideal)
