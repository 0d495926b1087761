"""Nonlinear plant: the robot's equations of motion integrated with fixed-step RK4.

The motor voltages are held between calls (zero-order hold, as the EV3's PWM does between
duty writes); the step is 1 ms by default, five per 5 ms control tick. A generalized force
can be added for pushes and other external disturbances.
"""
import numpy as np

from hostsim.model import RobotModel, state_scale_to_si

DEFAULT_DT_S = 1e-3


class Plant:
    """The simulated robot. ``x`` is in the model variant's units, ``x_si`` in SI."""

    def __init__(self, model, x0=None, dt_s=DEFAULT_DT_S):
        if not isinstance(model, RobotModel):
            raise TypeError("Plant needs a hostsim.model.RobotModel")
        if not dt_s > 0:
            raise ValueError("integration step must be positive, got %r" % dt_s)
        self.model = model
        self.dt_s = float(dt_s)
        self.t_s = 0.0
        self.x = np.zeros(10) if x0 is None else np.array(x0, dtype=float)
        if self.x.shape != (10,):
            raise ValueError("initial state must have 10 entries, got shape %s" % (self.x.shape,))
        self._to_si = np.diag(state_scale_to_si(model.variant)).copy()

    @property
    def x_si(self):
        return self.x * self._to_si

    def _deriv(self, x, u, f_ext):
        m, f = self.model.mass_matrix_forcing(x[:5], x[5:], u)
        if f_ext is not None:
            f = [fi + ei for fi, ei in zip(f, f_ext)]
        qdd = np.linalg.solve(np.array(m).reshape(5, 5), np.array(f))
        return np.concatenate((x[5:], qdd))

    def advance(self, u_v, duration_s, f_ext=None):
        """Integrate for duration_s (a whole number of steps) with inputs u_v held.

        u_v: 5 volts [u_r, u_l, 0, u_th2, u_th3]; f_ext: optional generalized force (5, in
        the model's units: N per unit of d, N m for the angles).
        """
        u = [float(v) for v in u_v]
        steps = int(round(duration_s / self.dt_s))
        if steps < 1 or abs(steps * self.dt_s - duration_s) > 1e-9:
            raise ValueError("duration %r s is not a whole number of %r s steps" % (duration_s, self.dt_s))
        h = self.dt_s
        x = self.x
        for _ in range(steps):
            k1 = self._deriv(x, u, f_ext)
            k2 = self._deriv(x + 0.5 * h * k1, u, f_ext)
            k3 = self._deriv(x + 0.5 * h * k2, u, f_ext)
            k4 = self._deriv(x + h * k3, u, f_ext)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        self.x = x
        self.t_s += steps * h
        return x

    def wheel_angles_rel_rad(self):
        """Wheel angles relative to link 1 (what the wheel encoders measure), radians."""
        x = self.x_si
        rw = self.model.params["rw_m"]
        return x[0] / rw - x[2], x[1] / rw - x[2]

    def fallen(self, limit_rad=np.pi / 2):
        return abs(self.x[2]) > limit_rad
