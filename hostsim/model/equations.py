"""Equations of motion of the wheeled three-link pendulum, derived with sympy.physics.mechanics.

Generalized coordinates q = [d_r, d_l, th1, th2, th3]: rolling displacement of the right
and left wheel (wheel radius x absolute wheel angle, positive forward), tilt of link 1 from
the vertical (positive forward), angle of link 2 relative to link 1 and of link 3 relative
to link 2. Inputs u = [u_r, u_l, u_th1, u_th2, u_th3] in volts, u_th1 = 0 (link 1 has no
motor). The equations are ``M(q) q'' = F(q, q', u)``.

Two variants share the kinematics and differ in the conventions listed in ``Variant``:

``paper``
    What reproduces Appendix C of the paper (see shared/paper/README.md): d in cm; the
    wheel mass block of the numbers (``C1 = m/2 + mw + 2 Jw/Rw^2``, ``C2 = -Jw/Rw^2``),
    which is what a Lagrangian gives with a turning term ``m ((d_r'-d_l')/2)^2 / 2`` and a
    wheel term ``Jw ((d_r'-d_l')/Rw)^2 / 2``; each link's inertia J_i counted with its
    *relative* joint rate (hence Appendix B's missing J2, J3 terms); the wheel torque acting
    on d (in cm) directly and no reaction on link 1; no rotor inertia, no viscous friction.
``physical``
    The real drivetrain: d in m; the robot turns (yaw rate (d_r'-d_l')/H) and each body's
    full inertia about its centre of mass is counted with its absolute angular velocity;
    wheels roll without slipping; each wheel motor's stator sits on link 1, so its torque
    acts on the wheel and, as a reaction, on link 1, and its back-EMF and friction depend on
    the wheel speed relative to link 1; the joint motors act between neighbouring links;
    Table 2's rotor inertia Jm (output side) and viscous friction beta, each switchable.

The symbolic derivation takes tens of seconds, so its result (the lambdified source) is
cached under ``.cache/`` keyed by this file's content, the variant and the sympy version.
"""
import dataclasses
import hashlib
import importlib.util
import os

import numpy as np

from hostsim.model.params import REQUIRED
from hostsim.paths import CACHE_DIR as _CACHE
from tipbot_fw.vocabulary import ACTUATED_INPUTS, INPUT_NAMES, STATE_NAMES  # noqa: F401  (the model's names)

Q_NAMES = STATE_NAMES[:5]
PARAM_ORDER = tuple(sorted(REQUIRED))
CACHE_DIR = os.path.join(_CACHE, "model")


@dataclasses.dataclass(frozen=True)
class Variant:
    """Modelling conventions of one variant (see the module docstring)."""

    name: str
    d_unit: str                      # unit of d_r, d_l in the state: "cm" or "m"
    paper_conventions: bool          # the Appendix C conventions instead of the physical ones
    include_motor_inertia: bool      # Table 2 Jm (reflected rotor inertia), physical only
    include_viscous_friction: bool   # Table 2 beta, physical only

    @property
    def d_scale_m(self):
        """Metres per unit of d in the state."""
        return {"cm": 0.01, "m": 1.0}[self.d_unit]

    @property
    def state_units(self):
        d, v = self.d_unit, self.d_unit + "/s"
        return (d, d, "rad", "rad", "rad", v, v, "rad/s", "rad/s", "rad/s")

    def options(self):
        return dataclasses.asdict(self)


VARIANTS = {
    "paper": Variant("paper", "cm", True, False, False),
    "physical": Variant("physical", "m", False, True, True),
}


def get_variant(name, **overrides):
    """The named variant, optionally with switches changed (e.g. include_motor_inertia=False)."""
    if name not in VARIANTS:
        raise KeyError("unknown model variant '%s' (known: %s)" % (name, ", ".join(sorted(VARIANTS))))
    return dataclasses.replace(VARIANTS[name], **overrides)


# ----------------------------------------------------------------------------------------
# Symbolic derivation
# ----------------------------------------------------------------------------------------

def derive(variant):
    """Derive the equations of motion symbolically.

    Returns a dict of sympy objects over plain symbols: ``M`` (5x5), ``F`` (5x1), energy
    ``E`` (T + V), the linearization ``dF_dq``, ``dF_dqd``, ``dF_du`` at the upright
    equilibrium, and the symbol tuples ``q``, ``qd``, ``u``, ``p``.
    """
    import sympy as sm
    import sympy.physics.mechanics as me

    p = {name: sm.Symbol(name, positive=True) for name in PARAM_ORDER}
    q = me.dynamicsymbols("d_r d_l th1 th2 th3")
    qd = [qi.diff(me.dynamicsymbols._t) for qi in q]
    u = sm.symbols("u_r u_l u_th2 u_th3")
    d_r, d_l, th1, th2, th3 = q
    dr_d, dl_d, th1_d, th2_d, th3_d = qd
    s = sm.Rational(1, 100) if variant.d_unit == "cm" else sm.Integer(1)
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    m1, m2, m3, mw = p["m1_kg"], p["m2_kg"], p["m3_kg"], p["mw_kg"]
    rw, track, g = p["rw_m"], p["track_m"], p["g_m_s2"]
    jw = p["jw_kg_m2"]

    # Y: the robot's heading frame (x forward, y to the left along the axle, z up).
    N = me.ReferenceFrame("N")
    Y = me.ReferenceFrame("Y")
    yaw_rate = 0 if variant.paper_conventions else s * (dr_d - dl_d) / track
    Y.set_ang_vel(N, yaw_rate * Y.z)
    L1 = Y.orientnew("L1", "Axis", [th1, Y.y])
    L2 = L1.orientnew("L2", "Axis", [th2, L1.y])
    L3 = L2.orientnew("L3", "Axis", [th3, L2.y])
    WR = Y.orientnew("WR", "Axis", [s * d_r / rw, Y.y])
    WL = Y.orientnew("WL", "Axis", [s * d_l / rw, Y.y])

    axle = me.Point("O")
    axle.set_vel(N, s * (dr_d + dl_d) / 2 * Y.x)
    wheel_r = axle.locatenew("CR", -track / 2 * Y.y)
    wheel_l = axle.locatenew("CL", track / 2 * Y.y)
    for c in (wheel_r, wheel_l):
        c.v2pt_theory(axle, N, Y)
    # Links are uniform rods of length 2 l_i, stacked: joint i+1 sits at the end of link i.
    com1 = axle.locatenew("P1", l1 * L1.z)
    joint2 = axle.locatenew("J2", 2 * l1 * L1.z)
    com2 = joint2.locatenew("P2", l2 * L2.z)
    joint3 = joint2.locatenew("J3", 2 * l2 * L2.z)
    com3 = joint3.locatenew("P3", l3 * L3.z)
    com1.v2pt_theory(axle, N, L1)
    joint2.v2pt_theory(axle, N, L1)
    com2.v2pt_theory(joint2, N, L2)
    joint3.v2pt_theory(joint2, N, L2)
    com3.v2pt_theory(joint3, N, L3)

    links = ((m1, p["j1_kg_m2"], com1, L1), (m2, p["j2_kg_m2"], com2, L2), (m3, p["j3_kg_m2"], com3, L3))
    rel_rates = (th1_d, th2_d, th3_d)
    mass = m1 + m2 + m3
    half = sm.Rational(1, 2)

    if variant.paper_conventions:
        T = sum(half * m * com.vel(N).dot(com.vel(N)) for m, _, com, _ in links)
        T += sum(half * j * w ** 2 for (_, j, _, _), w in zip(links, rel_rates))
        turning = s * (dr_d - dl_d)
        T += half * mass * (turning / 2) ** 2 + half * jw * (turning / rw) ** 2
        T += sum(half * mw * (s * v) ** 2 + half * jw * (s * v / rw) ** 2 for v in (dr_d, dl_d))
    else:
        bodies = []
        for i, (m, j, com, frame) in enumerate(links, start=1):
            # Rods: J about both transverse axes; about their own axis, the yaw inertia of a
            # slab spanning the wheel track (Table 1 gives no value; it matters only in turns).
            inertia = me.inertia(frame, j, j, m * track ** 2 / 12)
            bodies.append(me.RigidBody("link%d" % i, com, frame, m, (inertia, com)))
        for name, frame, centre in (("wheel_r", WR, wheel_r), ("wheel_l", WL, wheel_l)):
            inertia = me.inertia(frame, jw / 2, jw, jw / 2)
            bodies.append(me.RigidBody(name, centre, frame, mw, (inertia, centre)))
        T = sum(b.kinetic_energy(N) for b in bodies)
        if variant.include_motor_inertia:
            # Jm of Table 2 is referred to the output shaft; it spins with the output
            # relative to the motor's housing.
            T += half * p["right_wheel_jm_kg_m2"] * (s * dr_d / rw - th1_d) ** 2
            T += half * p["left_wheel_jm_kg_m2"] * (s * dl_d / rw - th1_d) ** 2
            T += half * p["joint2_jm_kg_m2"] * th2_d ** 2
            T += half * p["joint3_jm_kg_m2"] * th3_d ** 2

    V = g * sum(m * com.pos_from(axle).dot(Y.z) for m, _, com, _ in links)

    def motor_torque(role, volts, rel_speed):
        km, ke, ra = p[role + "_km_nm_a"], p[role + "_ke_v_s"], p[role + "_ra_ohm"]
        damping = km * ke / ra
        if variant.include_viscous_friction and not variant.paper_conventions:
            damping += p[role + "_beta_nm_s"]
        return km / ra * volts - damping * rel_speed

    u_r, u_l, u_2, u_3 = u
    if variant.paper_conventions:
        # The paper: the wheel torque is the generalized force on d (in cm) itself, its speed
        # is d'/Rw (both in cm, i.e. the wheel's absolute rate), and link 1 feels no reaction.
        Q = sm.Matrix([
            motor_torque("right_wheel", u_r, s * dr_d / rw),
            motor_torque("left_wheel", u_l, s * dl_d / rw),
            0,
            motor_torque("joint2", u_2, th2_d),
            motor_torque("joint3", u_3, th3_d),
        ])
    else:
        tau_r = motor_torque("right_wheel", u_r, s * dr_d / rw - th1_d)
        tau_l = motor_torque("left_wheel", u_l, s * dl_d / rw - th1_d)
        tau_2 = motor_torque("joint2", u_2, th2_d)
        tau_3 = motor_torque("joint3", u_3, th3_d)
        # Each motor is a torque pair between the body carrying its stator and its output.
        pairs = ((WR, L1, tau_r), (WL, L1, tau_l), (L2, L1, tau_2), (L3, L2, tau_3))
        Q = sm.zeros(5, 1)
        for out_frame, stator_frame, tau in pairs:
            for frame, sign in ((out_frame, 1), (stator_frame, -1)):
                w = frame.ang_vel_in(N)
                for i, qdi in enumerate(qd):
                    # Partial angular velocities; Y has no orientation to N (only a yaw rate),
                    # and no measure number in Y depends on the rates except through them.
                    Q[i] += sign * tau * w.diff(qdi, Y).dot(Y.y)

    lm = me.LagrangesMethod(T - V, q)
    lm.form_lagranges_equations()
    M = lm.mass_matrix
    F = lm.forcing + Q

    qs = sm.symbols("q0:5")
    qds = sm.symbols("qd0:5")
    sub = dict(zip(qd, qds))
    sub.update(dict(zip(q, qs)))
    M = me.msubs(M, sub)
    F = me.msubs(F, sub)
    E = me.msubs(T + V, sub)
    zero = {x: 0 for x in qs + qds + u}
    dF_dq = F.jacobian(qs).subs(zero)
    dF_dqd = F.jacobian(qds).subs(zero)
    dF_du = F.jacobian(u).subs(zero)
    return dict(M=M, F=F, E=E, dF_dq=dF_dq, dF_dqd=dF_dqd, dF_du=dF_du,
                q=qs, qd=qds, u=u, p=tuple(p[n] for n in PARAM_ORDER))


def _scalar_function(name, args, exprs):
    """Source of a plain-``math`` function over Python floats returning a flat list.

    sympy.cse with its basic optimizations shrinks the equations roughly tenfold; scalar
    code over floats then costs a few microseconds, which the simulator's 1 kHz
    integration of hundreds of Monte Carlo runs needs.
    """
    import sympy as sm
    from sympy.printing.pycode import PythonCodePrinter

    printer = PythonCodePrinter({"fully_qualified_modules": False})
    replacements, reduced = sm.cse(exprs, optimizations="basic")
    lines = ["def %s(%s):" % (name, ", ".join(a for a, _ in args))]
    for argname, symbols in args:
        lines.append("    %s, = %s" % (", ".join(str(x) for x in symbols), argname))
    for sym, expr in replacements:
        lines.append("    %s = %s" % (sym, printer.doprint(expr)))
    lines.append("    return [%s]" % ", ".join(printer.doprint(e) for e in reduced))
    return "\n".join(lines) + "\n"


def _generate_source(variant):
    """Python source of the numeric functions of one variant (see _scalar_function)."""
    sym = derive(variant)
    q, qd, u, p = sym["q"], sym["qd"], sym["u"], sym["p"]
    chunks = ["# Generated by hostsim.model.equations from variant %r; do not edit.\n" % variant.name,
              "from math import *\n"]
    funcs = (
        ("mass_matrix_forcing", (("q", q), ("qd", qd), ("u", u), ("p", p)), list(sym["M"]) + list(sym["F"])),
        ("energy", (("q", q), ("qd", qd), ("p", p)), [sym["E"]]),
        ("linearization", (("p", p),), list(sym["dF_dq"]) + list(sym["dF_dqd"]) + list(sym["dF_du"])),
    )
    for name, args, exprs in funcs:
        chunks.append(_scalar_function(name, args, exprs))
    return "\n".join(chunks)


def _cache_key(variant):
    import sympy

    with open(__file__, "rb") as f:
        text = f.read()
    blob = text + repr(sorted(variant.options().items())).encode() + sympy.__version__.encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def _load_functions(variant):
    path = os.path.join(CACHE_DIR, "%s-%s.py" % (variant.name, _cache_key(variant)))
    if not os.path.exists(path):
        source = _generate_source(variant)
        os.makedirs(CACHE_DIR, exist_ok=True)
        tmp = path + ".tmp%d" % os.getpid()
        with open(tmp, "w") as f:
            f.write(source)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location("tipbot_model_" + variant.name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class RobotModel:
    """Numeric equations of motion of one variant with one set of parameters.

    States and inputs are in the variant's units (``state_units``; volts for inputs).
    """

    def __init__(self, variant, params):
        if isinstance(variant, str):
            variant = get_variant(variant)
        self.variant = variant
        self.params = dict(params)
        self._pl = [float(self.params[n]) for n in PARAM_ORDER]
        self._f = _load_functions(variant)
        self.state_units = variant.state_units

    @property
    def u_max_v(self):
        return self.params["u_max_v"]

    def mass_matrix_forcing(self, q, qd, u):
        """(M, F) as flat Python lists (25 and 5 floats); u has 5 entries, u_th1 unused."""
        out = self._f.mass_matrix_forcing(list(q), list(qd), (u[0], u[1], u[3], u[4]), self._pl)
        return out[:25], out[25:]

    def mass_matrix(self, q):
        m, _ = self.mass_matrix_forcing(q, np.zeros(5), np.zeros(5))
        return np.array(m, dtype=float).reshape(5, 5)

    def forcing(self, q, qd, u):
        """F(q, q', u) with u the 5 inputs; u_th1 must be 0 (there is no motor)."""
        return np.array(self.mass_matrix_forcing(q, qd, u)[1], dtype=float)

    def qdd(self, q, qd, u):
        m, f = self.mass_matrix_forcing(q, qd, u)
        return np.linalg.solve(np.array(m).reshape(5, 5), np.array(f))

    def xdot(self, x, u):
        x = np.asarray(x, dtype=float)
        return np.concatenate((x[5:], self.qdd(x[:5], x[5:], u)))

    def energy(self, q, qd):
        """Kinetic plus potential energy in joules (for the conservation check)."""
        return float(self._f.energy(list(q), list(qd), self._pl)[0])

    def linearize(self):
        """Continuous-time (Ac, Bc) at the upright equilibrium, in the variant's units."""
        m0 = self.mass_matrix(np.zeros(5))
        lin = np.array(self._f.linearization(self._pl), dtype=float)
        fq = lin[:25].reshape(5, 5)
        fqd = lin[25:50].reshape(5, 5)
        fu = lin[50:].reshape(5, 4)
        ac = np.zeros((10, 10))
        ac[:5, 5:] = np.eye(5)
        ac[5:, :5] = np.linalg.solve(m0, fq)
        ac[5:, 5:] = np.linalg.solve(m0, fqd)
        bc = np.zeros((10, 5))
        bc[5:, list(ACTUATED_INPUTS)] = np.linalg.solve(m0, fu)
        return ac, bc


def state_scale_to_si(variant):
    """Diagonal S with x_si = S x_variant (cm -> m for the wheel displacements and rates)."""
    k = variant.d_scale_m
    return np.diag([k, k, 1, 1, 1, k, k, 1, 1, 1]).astype(float)
