"""Nonlinear plant: the robot's equations of motion integrated with a fixed step.

The motor voltages are held between calls (zero-order hold, as the EV3's PWM does between
duty writes); the step is 1 ms by default, five per 5 ms control tick. A generalized force
can be added for pushes and other external disturbances.

Integration: classic RK4 (``method="rk4"``, the default and the reference) or Heun's
second-order method (``"heun"``, half the derivative evaluations; its error against RK4 at
1 ms is bounded by tests/test_sim_plant.py; ``python -m hostsim bench-sim`` times both). Without an
external force the derivative comes from hostsim.model.fastdyn, which gives bit-for-bit the
numbers of the model's mass_matrix_forcing + solve_spd5 below at about half the cost.
"""
import math

import numpy as np

from hostsim.model import fastdyn
from hostsim.model.equations import RobotModel, state_scale_to_si

DEFAULT_DT_S = 1e-3
METHODS = ("rk4", "heun")


def solve_spd5(m, f):
    """Solve M a = f for the 5x5 symmetric positive definite M (flat row-major list).

    Cholesky in plain Python: for a 5x5 system this is several times cheaper than a numpy
    call on Python floats, and the simulator solves it four times per millisecond.
    """
    n = 5
    low = [[0.0] * n for _ in range(n)]
    for i in range(n):
        row = low[i]
        for j in range(i + 1):
            s = m[i * n + j]
            lj = low[j]
            for k in range(j):
                s -= row[k] * lj[k]
            if i == j:
                if s <= 0.0:
                    raise np.linalg.LinAlgError("mass matrix is not positive definite")
                row[i] = math.sqrt(s)
            else:
                row[j] = s / lj[j]
    y = [0.0] * n
    for i in range(n):
        s = f[i]
        row = low[i]
        for k in range(i):
            s -= row[k] * y[k]
        y[i] = s / row[i]
    a = [0.0] * n
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= low[k][i] * a[k]
        a[i] = s / low[i][i]
    return a


class Plant:
    """The simulated robot. ``x`` is in the model variant's units, ``x_si`` in SI."""

    def __init__(self, model, x0=None, dt_s=DEFAULT_DT_S, method="rk4"):
        if not isinstance(model, RobotModel):
            raise TypeError("Plant needs a hostsim.model.RobotModel")
        if not dt_s > 0:
            raise ValueError("integration step must be positive, got %r" % dt_s)
        if method not in METHODS:
            raise ValueError("integration method must be one of %s, got %r" % (", ".join(METHODS), method))
        self.method = method
        self._fast, self._pre = fastdyn.compile_model(model)
        self.model = model
        self.dt_s = float(dt_s)
        self.t_s = 0.0
        self.x = np.zeros(10) if x0 is None else np.array(x0, dtype=float)
        if self.x.shape != (10,):
            raise ValueError("initial state must have 10 entries, got shape %s" % (self.x.shape,))
        self._to_si = np.diag(state_scale_to_si(model.variant)).copy()
        self.load = None      # hostsim.world.load.Load: a payload schedule, a sloped floor

    def set_params(self, params):
        """Switch to the same model with other parameters (a payload put on or taken off),
        keeping the state: no impulse."""
        self.model = RobotModel(self.model.variant, params)
        self._fast, self._pre = fastdyn.compile_model(self.model)
        if self.load is not None:
            self.load.set_params(self.model.params)

    def _load_due(self, t_s):
        params = self.load.due(t_s)
        if params is not None:
            self.set_params(params)

    @property
    def x_si(self):
        return self.x * self._to_si

    def _deriv(self, x, u, f_ext):
        """[q', q''] at state x (a list of floats): the hot path, so plain Python."""
        qd = x[5:]
        m, f = self.model.mass_matrix_forcing(x[:5], qd, u)
        if f_ext is not None:
            f = [fi + ei for fi, ei in zip(f, f_ext)]
        return qd + solve_spd5(m, f)

    def motor_angles(self):
        """The angles the 4 motors' encoders measure (rad): each wheel relative to link 1
        (d / R_w - th1), the joints (th2, th3)."""
        x = self.x_si.tolist()
        rw = self.model.params["rw_m"]
        return [x[0] / rw - x[2], x[1] / rw - x[2], x[3], x[4]]

    def motor_speeds(self):
        x = self.x_si.tolist()
        rw = self.model.params["rw_m"]
        return [x[5] / rw - x[7], x[6] / rw - x[7], x[8], x[9]]

    def apply_impulse(self, p_gen):
        """Add a generalized impulse (5, the model's units: N s per unit of d, N m s for the
        angles) to the speeds: q' += M(q)^-1 p_gen."""
        self.x[5:] += np.linalg.solve(self.model.mass_matrix(self.x[:5]), np.asarray(p_gen, dtype=float))

    def advance(self, u_v, duration_s, f_ext=None):
        """Integrate for duration_s with inputs u_v held (steps of dt_s, a shorter last one).

        u_v: 5 volts [u_r, u_l, 0, u_th2, u_th3]; f_ext: optional generalized force (5, in
        the model's units: N per unit of d, N m for the angles).
        """
        u = [float(v) for v in u_v]
        f_ext = None if f_ext is None else [float(v) for v in f_ext]
        if not duration_s > 0:
            raise ValueError("duration must be positive, got %r" % duration_s)
        if self.load is not None:
            return self._advance_loaded(u, duration_s, f_ext)
        if f_ext is None:
            pre = self._pre
            fast = self._fast

            def deriv(x, u, _):
                return fast(x, u, pre)
        else:
            deriv = self._deriv
        x = [float(v) for v in self.x]
        remaining = float(duration_s)
        heun = self.method == "heun"
        while remaining > 1e-12:
            h = min(self.dt_s, remaining)
            k1 = deriv(x, u, f_ext)
            if heun:
                k2 = deriv([a + h * b for a, b in zip(x, k1)], u, f_ext)
                x = [a + (0.5 * h) * (b + c) for a, b, c in zip(x, k1, k2)]
            else:
                k2 = deriv([a + 0.5 * h * b for a, b in zip(x, k1)], u, f_ext)
                k3 = deriv([a + 0.5 * h * b for a, b in zip(x, k2)], u, f_ext)
                k4 = deriv([a + h * b for a, b in zip(x, k3)], u, f_ext)
                x = [a + (h / 6.0) * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
            remaining -= h
        self.x = np.array(x)
        self.t_s += duration_s
        return self.x

    def _advance_loaded(self, u, duration_s, f_ext):
        """advance() with self.load: its parameter steps at their times, the floor's frame at
        each step's start, its force at every evaluation (hostsim.world.load)."""
        ext, _ = fastdyn.compile_model_ext(self.model)
        zeros_m = [0.0] * 15
        load = self.load

        def deriv(x):
            f = load.force(x) or [0.0] * 5
            if f_ext is not None:
                f = [a + b for a, b in zip(f, f_ext)]
            return ext(x, u, self._pre, zeros_m + f, ())

        x = [float(v) for v in self.x]
        t = self.t_s
        remaining = float(duration_s)
        heun = self.method == "heun"
        while remaining > 1e-12:
            self._load_due(t)
            x = load.reframe(x)
            h = min(self.dt_s, remaining)
            k1 = deriv(x)
            if heun:
                k2 = deriv([a + h * b for a, b in zip(x, k1)])
                x = [a + (0.5 * h) * (b + c) for a, b, c in zip(x, k1, k2)]
            else:
                k2 = deriv([a + 0.5 * h * b for a, b in zip(x, k1)])
                k3 = deriv([a + 0.5 * h * b for a, b in zip(x, k2)])
                k4 = deriv([a + h * b for a, b in zip(x, k3)])
                x = [a + (h / 6.0) * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
            remaining -= h
            t += h
        self.x = np.array(x)
        self.t_s += duration_s
        return self.x


def link_push_impulse(model, q, link, impulse_n_s):
    """The generalized impulse (5, the model's units) of a horizontal impulse (N s, forward
    positive) at the centre of mass of link 1, 2 or 3, with the robot at q: J^T P, J the
    partial derivatives of that point's forward position (the links are rods of length 2 l_i
    stacked on the axle, hostsim.model.equations)."""
    p = model.params
    th1, th12 = q[2], q[2] + q[3]
    th123 = th12 + q[4]
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    half_d = 0.5 * model.variant.d_scale_m        # the axle moves by (d_r + d_l) / 2
    if link == 1:
        j = [half_d, half_d, l1 * math.cos(th1), 0.0, 0.0]
    elif link == 2:
        j = [half_d, half_d, 2 * l1 * math.cos(th1) + l2 * math.cos(th12), l2 * math.cos(th12), 0.0]
    elif link == 3:
        c3 = l3 * math.cos(th123)
        c2 = 2 * l2 * math.cos(th12) + c3
        j = [half_d, half_d, 2 * l1 * math.cos(th1) + c2, c2, c3]
    else:
        raise ValueError("link must be 1, 2 or 3, got %r" % (link,))
    return [impulse_n_s * v for v in j]


def disturbance_at(sc, t_s):
    """The disturbance vector w (volts, 5) a scenario (hostsim.sim.scenario.Disturbance) has in
    force at time t_s."""
    w = [0.0] * 5
    for d in sc.disturbances:
        if d.t_start_s <= t_s < d.t_end_s:
            w = [a + b for a, b in zip(w, d.w_v)]
    return w


def apply_push(plant, push):
    """A scenario push (hostsim.sim.scenario.Push) on the plant, now."""
    if push.impulse_n_s is None:
        plant.x[7] += push.th1_dot_rad_s
    else:
        plant.apply_impulse(link_push_impulse(plant.model, plant.x[:5], push.link, push.impulse_n_s))
