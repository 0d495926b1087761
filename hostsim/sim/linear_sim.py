"""The paper's simulation: an estimator and the controller on the linear or nonlinear model.

Linear: plant x_{k+1} = A x_k + B (u_k + w_k) (input disturbances, E = B), full-state
measurement y = x. Nonlinear: the same loop around hostsim.world.plant, the input (plus w) held
over each tick, y = x sampled at the ticks. The estimator is the paper's detector (the default
of these modes, for reproducing the paper) or the firmware's default one, the Kalman filter of
the gains' `kalman` block fed the ideal measurement of the true state (KalmanController); the
control law is that of docs/architecture.md, with the same saturation as the firmware. Written
in floats, independently of the firmware's fixed-point core, so that comparing the two tests
the firmware's implementation.

Everything here is SI (m, rad, V): the gains are a tipbot_fw.gains.Gains, which the firmware's
own loader validated and converted to SI (a gains file in paper units, cm, included).
"""
import numpy as np

from hostsim.errors import TipbotError
from hostsim.model import design
from hostsim.model.params import scaled_params
from hostsim.model.equations import RobotModel, state_scale_to_si
from hostsim.sim.governor import ReferenceGovernor
from hostsim.sim.result import RunResult
from hostsim.world.plant import Plant, disturbance_at
from hostsim.sim.scenario import scenario_load
from tipbot_fw.cores.kalman_design import reference_step
from tipbot_fw.vocabulary import ACTUATED_INPUTS

ESTIMATORS = ("detector", "kalman")

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


class KalmanController:
    """The firmware's default estimator and law, in floats (SI, one tick at a time): the gains'
    Kalman filter (its `kalman` block: the filter's model, gain L and law K_a, with the law's
    integrators where the gains have them), tipbot_fw.cores.kalman_design.reference_step,
    measuring m = C_a x of the true state: the wheel angles relative to link 1, the joints, the
    gyro's rate, ideal (no quantization, no bias). The estimate starts at xhat0 (the robot's
    states), no disturbance, no bias. With ``k_pd`` (5x10, SI) the law is u = -K_pd x^."""

    def __init__(self, g, xhat0, k_pd=None):
        kal = g.kalman
        if kal is None:
            raise TipbotError("the Kalman estimator needs gains with a kalman block")
        self.g, self.kal, self.k_pd = g, kal, k_pd
        self.c_x = kal.C[:, :10]
        self.w_at = [(10 + j, ACTUATED_INPUTS[i]) for j, i in enumerate(kal.disturbance_inputs)]
        self.xf = np.zeros(kal.n)
        self.xf[:10] = xhat0
        self._set(-kal.K @ self.xf)

    def _set(self, u_act):
        """The tick's estimate views and its input (u_act: the law's 4 actuated inputs)."""
        self.xh = self.xf[:10]
        self.w_hat = np.zeros(5)
        for j, i in self.w_at:
            self.w_hat[i] = self.xf[j]
        self.u_unsat = np.zeros(5)
        if self.k_pd is not None:
            self.u_unsat = -self.k_pd @ self.xh
        else:
            self.u_unsat[ACTUATED_INPUTS] = u_act
        self.u = _saturate(self.u_unsat, self.g.u_max_v)

    def update(self, y_next):
        """Read the true state y_{k+1} (y = x): the filter's update, return u_{k+1} (saturated)."""
        self.xf, u_act = reference_step(self.kal, self.xf, self.u[ACTUATED_INPUTS], self.c_x @ y_next)
        self._set(u_act)
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


def _controller(g, sc, k_pd, x, ideal, estimator):
    xhat0 = sc.xhat0_si if sc.xhat0_si is not None else sc.x0_si
    if estimator not in ESTIMATORS:
        raise TipbotError("estimator %r: one of %s" % (estimator, ", ".join(ESTIMATORS)))
    if ideal:
        return IdealController(g, sc, x)
    if estimator == "kalman":
        if sc.reference_governor and k_pd is None:
            raise TipbotError("scenario %s: the reference governor leads the paper's detector law, not the "
                              "Kalman filter's" % sc.name)
        return KalmanController(g, xhat0, k_pd)
    governor = ReferenceGovernor(g, xhat0) if sc.reference_governor and k_pd is None else None
    return HostController(g, xhat0, g.C @ x, k_pd, governor)


def _simulate(g, sc, k_pd, x0, step, fallen, ideal=False, estimator="detector"):
    n_steps = int(round(sc.duration_s / g.ts_s))
    x = np.array(x0, dtype=float)
    ctl = _controller(g, sc, k_pd, x, ideal, estimator)
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


def simulate_linear(g, sc, k_pd=None, params=None, estimator="detector"):
    """Run a scenario on the linear model -> RunResult (SI). estimator: "detector" (the
    paper's) or "kalman" (the firmware's default, KalmanController)."""
    a, b = truth_linear_model(g, sc, params)
    return _simulate(g, sc, k_pd, sc.x0_si, lambda x, u, t: a @ x + b @ u, lambda x: False, estimator=estimator)


def simulate_nonlinear(g, sc, k_pd=None, params=None, fall_rad=np.pi / 2, ideal=False, estimator="detector"):
    """Run a scenario on the nonlinear plant with ideal measurement -> RunResult (SI).

    Stops early (completed=False) when |th1| passes fall_rad: the model means nothing once
    the robot lies on the floor. ideal: the IdealController (true state and disturbance)
    instead of an estimator; estimator: as simulate_linear's.
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

    return _simulate(g, sc, k_pd, sc.x0_si, step, lambda x: abs(x[2]) > fall_rad, ideal, estimator)
