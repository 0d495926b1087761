"""The drivetrain the ideal plant leaves out: each motor's rotor as its own body, Coulomb
friction with stick-slip, and gear backlash (a free play between the rotor and its load).

hostsim.world.plant integrates the robot with every rotor rigidly on its output (Table 2's
Jm in the mass matrix, viscous friction only). :class:`DrivetrainPlant` keeps that model
while a motor is *engaged* and takes the rotor out while it is *free*:

- **Engaged** (always, without backlash): the rotor turns with its load, exactly as in the
  plant's equations. Coulomb friction ``tau`` (N m, output side) acts on that motion; when
  the motion stops, the motor *sticks*: its load direction is locked by a constraint force
  (solved exactly, see ``_solve``) as long as that force stays within ``tau``, and breaks
  away when it does not. This is a proper stick-slip treatment (Karnopp-style, decided once
  per integration step), not a smoothed friction curve: a duty below the break-away does not
  move a free motor at all (tests/test_drivetrain.py).
- **Free** (backlash only): the rotor (inertia Jm, the motor torque with its back-EMF and
  viscous friction, and its Coulomb friction) moves inside the gap without touching the
  load, and the load moves without motor torque. When the gap closes the two meet in a
  plastic impact (momentum conserved, relative speed zeroed) and the motor is engaged on
  that side; it separates again when the contact torque would have to pull.

Which angle an encoder reads: the rotor's (the EV3's encoder sits on the motor side of the
gear train; the published backlash is at the output shaft, ../shared/ev3-hardware.md), so
inside the free play the encoder moves while the wheel does not, and the other way round.

Events (sticking, breaking away, impacts, separation) are detected at the end of each
integration step (1 ms) and the modes are held over a step: first-order in time at the
events, which at 1 ms and the robot's speeds is far below one encoder count.

Only the ``physical`` variant has rotors (Jm) in its mass matrix; the ``paper`` variant has
none to take out, so it is refused.
"""
import numpy as np

from hostsim.model import fastdyn
from hostsim.world.plant import Plant
from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.vocabulary import ACTUATED_INPUTS

# A locked motor whose load moves faster than this (a push) is no longer stuck; below it a
# speed is round-off of the projection that locked it.
STUCK_SPEED_RAD_S = 1e-6

_HEUN = ((), (1.0,)), (0.5, 0.5)
_RK4 = ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)), (1.0 / 6, 1.0 / 3, 1.0 / 3, 1.0 / 6)
TABLEAUS = {"heun": _HEUN, "rk4": _RK4}


def _tri(i, j):
    """Index of M[i][j] (i >= j) in the lower triangle, row by row (fastdyn's e)."""
    return i * (i + 1) // 2 + j


def _sign(v):
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


def _dot(a, v):
    return a[0] * v[0] + a[1] * v[1] + a[2] * v[2] + a[3] * v[3] + a[4] * v[4]


def motor_directions(rw_m):
    """Per motor, the load angle it drives as a combination of q = [d_r, d_l, th1, th2, th3]:
    a wheel's angle relative to link 1 (d/R_w - th1, its stator sits on link 1), the joints'."""
    k = 1.0 / rw_m
    return ((k, 0.0, -1.0, 0.0, 0.0), (0.0, k, -1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 0.0, 1.0))


class _Motor(object):
    __slots__ = ("a", "ia", "aat", "jm", "k_v", "c", "tau", "gap", "inp", "free", "side", "phi", "omega", "stuck",
                 "slip", "lam")

    def __init__(self, a, jm, k_v, c, tau, gap, inp):
        self.a = a
        nz = [(i, v) for i, v in enumerate(a) if v != 0.0]
        if len(nz) == 1:
            nz.append((nz[0][0], 0.0))
        self.ia = (nz[0][0], nz[0][1], nz[1][0], nz[1][1])     # a's (at most two) nonzero entries
        self.aat = [(_tri(i, j), a[i] * a[j]) for i in range(5) for j in range(i + 1) if a[i] * a[j] != 0.0]
        self.jm, self.k_v, self.c, self.tau, self.gap, self.inp = jm, k_v, c, tau, gap, inp
        self.free = gap > 0.0        # starts in the middle of its free play
        self.side = 0.0              # engaged on this side of the gap (+1 rotor ahead, -1 behind)
        self.phi = 0.0               # rotor angle (output side, relative to its stator), rad
        self.omega = 0.0
        self.stuck = tau > 0.0       # at rest, friction holds it
        self.slip = 0.0              # direction of the slipping motion, decided per step
        self.lam = 0.0               # locked: the constraint torque holding it (last step)


class DrivetrainPlant(Plant):
    """The physical plant with rotors, Coulomb friction and backlash (module docstring).

    friction_nm: Coulomb friction torque per motor (right wheel, left wheel, joint 2, joint 3;
    output side, N m); backlash_rad: the whole free play per motor (rad at the output).
    Same interface as Plant, plus motor_angles() (what the encoders see) and motor_speeds().
    """

    def __init__(self, model, x0=None, dt_s=None, method="heun", friction_nm=(0.0,) * 4, backlash_rad=(0.0,) * 4):
        v = model.variant
        if v.paper_conventions or not v.include_motor_inertia or v.d_unit != "m":
            raise ValueError("drivetrain effects (friction, backlash) need the physical model with rotor inertia, "
                             "not the %r variant" % v.name)
        kwargs = {} if dt_s is None else {"dt_s": dt_s}
        Plant.__init__(self, model, x0, method=method, **kwargs)
        self._ext, self._pre_ext = fastdyn.compile_model_ext(model)
        self._tableau = TABLEAUS[method]
        self._heun = method == "heun"
        p = model.params
        beta = v.include_viscous_friction
        self.motors = []
        for i, (role, a) in enumerate(zip(MOTOR_ROLES, motor_directions(p["rw_m"]))):
            km, ke, ra = p[role + "_km_nm_a"], p[role + "_ke_v_s"], p[role + "_ra_ohm"]
            c = km * ke / ra + (p[role + "_beta_nm_s"] if beta else 0.0)
            self.motors.append(_Motor(a, p[role + "_jm_kg_m2"], km / ra, c, float(friction_nm[i]),
                                      float(backlash_rad[i]), ACTUATED_INPUTS[i]))
        q0 = self.x[:5]
        for m in self.motors:
            m.phi = _dot(m.a, q0)
        self.impacts = 0

    # ------------------------------------------------------------------ what the sensors see
    def motor_angles(self):
        """Rotor angles (rad, output side, relative to the stator) of the 4 motors."""
        q = self.x.tolist()
        return [m.phi if m.free else q[m.ia[0]] * m.ia[1] + q[m.ia[2]] * m.ia[3] + 0.5 * m.side * m.gap
                for m in self.motors]

    def motor_speeds(self):
        x = self.x.tolist()
        return [m.omega if m.free else x[5 + m.ia[0]] * m.ia[1] + x[5 + m.ia[2]] * m.ia[3] for m in self.motors]

    def load_angles(self):
        """The angles the motors drive, on the load side of the free play (rad)."""
        q = self.x.tolist()
        return [_dot(m.a, q) for m in self.motors]

    # ------------------------------------------------------------------ integration
    def advance(self, u_v, duration_s, f_ext=None):
        if f_ext is not None:
            raise ValueError("DrivetrainPlant takes no external force")
        if not duration_s > 0:
            raise ValueError("duration must be positive, got %r" % duration_s)
        u = [float(v) for v in u_v]
        x = self.x.tolist()
        remaining = float(duration_s)
        t = self.t_s
        while remaining > 1e-12:
            if self.load is not None:
                self._load_due(t)
                x = self.load.reframe(x)
            h = min(self.dt_s, remaining)
            x = self._step(x, u, h)
            remaining -= h
            t += h
        self.x = np.array(x)
        self.t_s += duration_s
        return self.x

    def set_params(self, params):
        Plant.set_params(self, params)
        self._ext, self._pre_ext = fastdyn.compile_model_ext(self.model)

    def _modes(self, x, u):
        """Per-step constants: inputs with the free rotors' removed, M's and F's additions
        (constant generalized forces), the locked motors, the free ones."""
        u_eff = list(u)
        e = [0.0] * 20
        locked = []
        free = []
        for m in self.motors:
            i0, a0, i1, a1 = m.ia
            v = m.omega if m.free else x[5 + i0] * a0 + x[5 + i1] * a1
            if m.stuck and not m.free and abs(v) > STUCK_SPEED_RAD_S:
                m.stuck = False                 # pushed loose
            if not m.stuck and m.tau > 0.0 and abs(v) > STUCK_SPEED_RAD_S:
                # (a motor just released keeps the direction it broke away in: its speed
                # is still a round-off away from zero, of either sign)
                m.slip = 1.0 if v > 0.0 else -1.0
            if m.free:
                u_eff[m.inp] = 0.0
                jm = m.jm
                for idx, val in m.aat:
                    e[idx] -= jm * val
                free.append(m)
            elif m.stuck:
                locked.append(m)
            elif m.tau > 0.0:
                f = -m.tau * m.slip
                e[15 + i0] += f * a0
                e[15 + i1] += f * a1
        return u_eff, e, locked, free

    def _accel(self, x, u_eff, e, rhs, locked, free):
        """q'' with the free rotors out and the locked directions held; sets each locked
        motor's constraint torque ``lam``."""
        if free:
            e = list(e)
            for m in free:
                # the model applies back-EMF and viscous friction on the load's speed: undo
                i0, a0, i1, a1 = m.ia
                f = m.c * (x[5 + i0] * a0 + x[5 + i1] * a1)
                e[15 + i0] += f * a0
                e[15 + i1] += f * a1
        if self.load is not None:
            f = self.load.force(x)
            if f is not None:
                e = e[:15] + [a + b for a, b in zip(e[15:], f)]
        out = self._ext(x, u_eff, self._pre_ext, e, rhs)
        qdd = out[5:10]
        if locked:
            if len(locked) == 1:
                m = locked[0]
                i0, a0, i1, a1 = m.ia
                z = out[10:15]
                lam = -(qdd[i0] * a0 + qdd[i1] * a1) / (z[i0] * a0 + z[i1] * a1)
                m.lam = lam
                return [qdd[i] + lam * z[i] for i in range(5)]
            k = len(locked)
            z = [out[10 + 5 * j:15 + 5 * j] for j in range(k)]
            g = [[_dot(locked[i].a, z[j]) for j in range(k)] for i in range(k)]
            lam = _gauss(g, [-_dot(m.a, qdd) for m in locked])
            for j in range(k):
                lj, zj = lam[j], z[j]
                qdd = [qdd[i] + lj * zj[i] for i in range(5)]
                locked[j].lam = lj
        return qdd

    def _step(self, x, u, h):
        u_eff, e, locked, free = self._modes(x, u)
        rhs = [m.a for m in locked]
        if self._heun:
            qdd1 = self._accel(x, u_eff, e, rhs, locked, free)
            x1 = [x[i] + h * x[5 + i] for i in range(5)] + [x[5 + i] + h * qdd1[i] for i in range(5)]
            rot1 = [(m.omega, self._rotor_accel(m, u, m.omega)) for m in free]
            for m, (w, dw) in zip(free, rot1):
                m.phi, m.omega = m.phi + h * w, w + h * dw        # the predictor, for stage 2
            qdd = self._accel(x1, u_eff, e, rhs, locked, free)
            hh = 0.5 * h
            x = ([x[i] + hh * (x[5 + i] + x1[5 + i]) for i in range(5)]
                 + [x[5 + i] + hh * (qdd1[i] + qdd[i]) for i in range(5)])
            for m, (w, dw) in zip(free, rot1):
                w1 = m.omega
                m.phi = m.phi - h * w + hh * (w + w1)
                m.omega = w + hh * (dw + self._rotor_accel(m, u, w1))
            return self._events(x, u, qdd)
        stages, weights = self._tableau
        ks = []       # per stage: (x', [(phi', omega') of each free rotor])
        rot0 = [(m.phi, m.omega) for m in free]
        for coeffs in stages:
            xs = list(x)
            rot = list(rot0)
            for c, k in zip(coeffs, ks):
                if c:
                    xs = [xs[i] + h * c * k[0][i] for i in range(10)]
                    rot = [(r[0] + h * c * kr[0], r[1] + h * c * kr[1]) for r, kr in zip(rot, k[1])]
            qdd = self._accel(xs, u_eff, e, rhs, locked, free)
            ks.append((xs[5:] + qdd, [(r[1], self._rotor_accel(m, u, r[1])) for m, r in zip(free, rot)]))
        for w, k in zip(weights, ks):
            x = [x[i] + h * w * k[0][i] for i in range(10)]
            rot0 = [(r[0] + h * w * kr[0], r[1] + h * w * kr[1]) for r, kr in zip(rot0, k[1])]
        for m, (phi, omega) in zip(free, rot0):
            m.phi, m.omega = phi, omega
        return self._events(x, u, ks[-1][0][5:])

    def _rotor_accel(self, m, u, omega):
        if m.stuck:
            return 0.0
        return (m.k_v * u[m.inp] - m.c * omega - m.tau * m.slip) / m.jm

    def _minv(self, x, a):
        """M^-1 a with the free rotors out of M (for impulses)."""
        e = [0.0] * 20
        for m in self.motors:
            if m.free:
                for idx, val in m.aat:
                    e[idx] -= m.jm * val
        return self._ext(x, [0.0] * 5, self._pre_ext, e, [a])[10:15]

    def apply_impulse(self, p_gen):
        """Add a generalized impulse (5, the model's units) to the load's speeds; free rotors
        do not take part."""
        z = self._minv([float(v) for v in self.x], [float(v) for v in p_gen])
        self.x[5:] += z

    def _project(self, x):
        """x with the load's speeds projected so that every locked motor is at rest: the
        impulses along the locked directions that zero their speeds together (an impulse
        for one motor alone would set the others moving)."""
        locked = [m for m in self.motors if m.stuck and not m.free]
        if not locked:
            return x
        e = [0.0] * 20
        for m in self.motors:
            if m.free:
                for idx, val in m.aat:
                    e[idx] -= m.jm * val
        out = self._ext(x, [0.0] * 5, self._pre_ext, e, [m.a for m in locked])
        k = len(locked)
        z = [out[10 + 5 * j:15 + 5 * j] for j in range(k)]
        qd = x[5:]
        p = _gauss([[_dot(locked[i].a, z[j]) for j in range(k)] for i in range(k)], [-_dot(m.a, qd) for m in locked])
        for j in range(k):
            qd = [qd[i] + p[j] * z[j][i] for i in range(5)]
        return x[:5] + qd

    def _events(self, x, u, qdd):
        moved = False        # an impulse changed the load's speeds
        stopping = []        # engaged motors whose motion stopped (or reversed) in this step
        for m in self.motors:
            a = m.a
            if m.free:
                q, qd = x[:5], x[5:]
                rel = m.omega - _dot(a, qd)
                delta = m.phi - _dot(a, q)
                half = 0.5 * m.gap
                if (delta >= half and rel > 0.0) or (delta <= -half and rel < 0.0):
                    # plastic impact: the rotor and its load leave with one speed
                    z = self._minv(x, a)
                    p = rel / (1.0 / m.jm + _dot(a, z))
                    x = x[:5] + [x[5 + i] + p * z[i] for i in range(5)]
                    m.free, m.side, m.stuck = False, _sign(delta), False
                    m.omega = 0.0
                    self.impacts += 1
                    moved = True
                elif m.tau > 0.0:
                    drive = m.k_v * u[m.inp]
                    if m.stuck:
                        if abs(drive) > m.tau:
                            m.stuck, m.slip = False, _sign(drive)
                    elif m.slip * m.omega <= 0.0:      # stopped (or reversed) under friction
                        m.omega = 0.0
                        if abs(drive) <= m.tau:
                            m.stuck = True
                        else:
                            m.slip = _sign(drive)
                continue
            if m.stuck:
                if abs(m.lam) > m.tau:
                    m.stuck, m.slip = False, -_sign(m.lam)
            elif m.tau > 0.0 and m.slip * _dot(a, x[5:]) <= 0.0:
                stopping.append(m)
                continue
            self._separation(m, x, u, qdd)
        if stopping:
            # At rest, does friction hold them? Lock them (their remaining speed, a step's
            # worth of deceleration, zeroed with the other locked motors'), then ask what
            # torque holding them takes: beyond friction, they go on the other way at once.
            for m in stopping:
                m.stuck = True
            x = self._project(x)
            u_eff, e, locked, free = self._modes(x, u)
            qdd = self._accel(x, u_eff, e, [m.a for m in locked], locked, free)
            for m in stopping:
                if abs(m.lam) > m.tau:
                    m.stuck, m.slip = False, -_sign(m.lam)
                self._separation(m, x, u, qdd)
            return x
        return self._project(x) if moved else x

    def _separation(self, m, x, u, qdd):
        """An engaged motor with backlash lets go of its load when the contact would pull."""
        if m.gap > 0.0:
            a = m.a
            v = _dot(a, x[5:])
            tau_m = m.k_v * u[m.inp] - m.c * v
            if m.stuck:
                contact = tau_m + m.lam
            else:
                contact = tau_m - m.tau * m.slip - m.jm * _dot(a, qdd)
            if m.side * contact < 0.0:
                m.free = True
                m.phi = _dot(a, x[:5]) + 0.5 * m.side * m.gap
                m.omega = 0.0 if m.stuck else v


def _gauss(g, b):
    """Solve the small dense system g y = b (Gaussian elimination, partial pivoting)."""
    n = len(b)
    a = [list(row) + [bi] for row, bi in zip(g, b)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(a[r][c]))
        a[c], a[p] = a[p], a[c]
        piv = a[c][c]
        for r in range(c + 1, n):
            f = a[r][c] / piv
            if f:
                a[r] = [x - f * y for x, y in zip(a[r], a[c])]
    y = [0.0] * n
    for r in range(n - 1, -1, -1):
        s = a[r][n] - sum(a[r][k] * y[k] for k in range(r + 1, n))
        y[r] = s / a[r][r]
    return y
