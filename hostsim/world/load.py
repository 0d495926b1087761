"""What a load on link 3 and a sloped floor do to the plant (issue 22).

Payload: a point mass on link 3's axis at a distance from its joint. Link 3 and the mass
become one rigid body: mass m3 + m, centre of mass moved along the link, inertia about the
new centre by the parallel-axis theorem. The model's links are rods whose l3 is both half
the length and the CoM distance (hostsim.model.equations), but nothing sits above link 3,
so l3 enters its equations only as the CoM distance: the loaded link is the same model with
m3, l3, J3 changed (payload_params). Putting it on or taking it off is a step change of
those parameters; the speeds are kept (a hand sets the load down on the moving link and
lifts it off with it: no impulse, "a put-on from above carries no momentum").

Slope: the model is planar, its coordinates measured along and across the floor. A floor
that rises by alpha in the forward direction turns gravity in that frame: g cos(alpha)
across the floor, g sin(alpha) along it, backwards. The model already has g across the
floor; the rest is a generalized force -dV/dq with
V_extra = g sum m_i (x_i sin(alpha) + y_i (cos(alpha) - 1)), x_i along and y_i across the
floor from the axle, over the links and the wheels (the wheels roll along the incline, so
they are pulled along it too). On a constant slope this is exact.

A ramp (flat, ramp, flat): the link angles are measured from the normal of the floor under
the axle, so where the floor's angle changes (a kink) the frame turns by the change delta and
the state is re-expressed in the new frame, the robot itself unmoved: every absolute angle
kept, so th1 (from the floor's normal: th1 = lean from the vertical + alpha) grows by delta,
and so does each wheel's angle from the floor's frame, whose rolling distance d is R_w times
it (d += R_w delta: the encoders, which read the wheel against link 1, d / R_w - th1, and
every motor's angle are unchanged, as they must be). The speeds are kept: the axle's speed
turns with the floor (at 5 degrees the speed across the new floor a concave kink would
stop is 0.4 % of it; the impact is not modelled), the links' rates are absolute. The frame
changes at most once per integration step (1 ms), at its start; the position along the floor
is tracked apart from d (which the re-expression moves by R_w delta) so that a robot standing
at a kink is not moved to and fro across it.
"""
import math

from hostsim.model.params import payload_params


class Floor:
    """The floor's slope along the axle's path: alpha (rad, positive: rising forward) between
    ramp_start_m and ramp_end_m (along the floor from the axle's start), flat outside; with
    no ramp bounds, alpha everywhere."""

    def __init__(self, angle_rad, ramp_start_m=None, ramp_end_m=None):
        self.angle_rad = float(angle_rad)
        self.ramp_start_m = ramp_start_m
        self.ramp_end_m = ramp_end_m

    def angle_at(self, s_m):
        if self.ramp_start_m is not None and not (self.ramp_start_m <= s_m < self.ramp_end_m):
            return 0.0
        return self.angle_rad


class SlopeForce:
    """The generalized force (5, the model's units) of gravity's turn on a floor of angle
    ``angle_rad`` (the frame's: hostsim.world.load.Load keeps it), for one model's
    parameters (module docstring)."""

    def __init__(self, model, angle_rad):
        self.angle_rad = float(angle_rad)
        self.half_d = 0.5 * model.variant.d_scale_m
        self.set_params(model.params)

    def set_params(self, p):
        self.g = p["g_m_s2"]
        self.m1, self.m2, self.m3 = p["m1_kg"], p["m2_kg"], p["m3_kg"]
        self.l1, self.l2, self.l3 = p["l1_m"], p["l2_m"], p["l3_m"]
        self.m_all = self.m1 + self.m2 + self.m3 + 2.0 * p["mw_kg"]

    def at(self, x):
        """[Q_dr, Q_dl, Q_th1, Q_th2, Q_th3] at state x (a list, the model's units)."""
        a = self.angle_rad
        if a == 0.0:
            return [0.0] * 5
        gs, gc = self.g * math.sin(a), self.g * (math.cos(a) - 1.0)
        th1, th12 = x[2], x[2] + x[3]
        th123 = th12 + x[4]
        m1, m2, m3, l1, l2, l3 = self.m1, self.m2, self.m3, self.l1, self.l2, self.l3
        c1, c12, c123 = math.cos(th1), math.cos(th12), math.cos(th123)
        s1, s12, s123 = math.sin(th1), math.sin(th12), math.sin(th123)
        # sum m_i dx_i/dq and sum m_i dy_i/dq over the links (x_i = ... + l sin, y_i = ... + l cos)
        x3, y3 = m3 * l3 * c123, -m3 * l3 * s123
        x2 = (m2 + 2.0 * m3) * l2 * c12 + x3
        y2 = -(m2 + 2.0 * m3) * l2 * s12 + y3
        x1 = (m1 + 2.0 * m2 + 2.0 * m3) * l1 * c1 + x2
        y1 = -(m1 + 2.0 * m2 + 2.0 * m3) * l1 * s1 + y2
        qd = -gs * self.m_all * self.half_d
        return [qd, qd, -(gs * x1 + gc * y1), -(gs * x2 + gc * y2), -(gs * x3 + gc * y3)]


def equilibrium_lean_rad(params, angle_rad):
    """The lean of link 1 from the vertical (rad, forward positive) at which the robot stands
    still on a floor of angle_rad with both joints straight: the wheels' motors hold the
    whole robot's pull along the floor, R_w m g sin(alpha) in all, and their reaction on the
    body is what gravity's moment of the leaning links takes up (the body's centre of mass
    uphill of the axle)."""
    p = params
    m_all = p["m1_kg"] + p["m2_kg"] + p["m3_kg"] + 2.0 * p["mw_kg"]
    moment = (p["m1_kg"] * p["l1_m"] + p["m2_kg"] * (2.0 * p["l1_m"] + p["l2_m"])
              + p["m3_kg"] * (2.0 * p["l1_m"] + 2.0 * p["l2_m"] + p["l3_m"]))
    return math.asin(p["rw_m"] * m_all * math.sin(angle_rad) / moment)


class Load:
    """A run's payload schedule and floor, for hostsim.world.plant.Plant (its ``load``).

    payload: (mass_kg, distance_m, t_on_s, t_off_s or None) or None; floor: a Floor or None;
    times from the plant's start (its t_s); s0_m: the axle's position at the start (the
    floor's origin), in metres along d.
    """

    def __init__(self, model, payload=None, floor=None, s0_m=0.0):
        self.base_params = dict(model.params)
        self.events = []                  # (t_s, params), in time order
        if payload is not None:
            mass_kg, distance_m, t_on_s, t_off_s = payload
            self.events.append((float(t_on_s), payload_params(self.base_params, mass_kg, distance_m)))
            if t_off_s is not None:
                self.events.append((float(t_off_s), dict(self.base_params)))
        self.floor = None if floor is None or floor.angle_rad == 0.0 else floor
        self.half_d = 0.5 * model.variant.d_scale_m
        self.d_per_m = 1.0 / model.variant.d_scale_m
        self.rw_m = model.params["rw_m"]
        self.s0_m = float(s0_m)
        self.kinks = 0                    # frame changes so far (module docstring)
        self.slope = None if self.floor is None else SlopeForce(model, self.floor.angle_at(0.0))

    def due(self, t_s, eps_s=1e-9):
        """The parameters to switch to at t_s (the last event due), or None."""
        out = None
        while self.events and self.events[0][0] <= t_s + eps_s:
            out = self.events.pop(0)[1]
        return out

    def set_params(self, params):
        self.rw_m = params["rw_m"]
        if self.slope is not None:
            self.slope.set_params(params)

    def position_m(self, x):
        """Where the axle is along the floor from its start (m)."""
        return self.half_d * (x[0] + x[1]) - self.s0_m

    def reframe(self, x):
        """x (a list, the model's units) re-expressed in the frame of the floor under the axle
        if that floor's angle differs from the frame's (module docstring); x itself otherwise."""
        if self.floor is None:
            return x
        new = self.floor.angle_at(self.position_m(x))
        delta = new - self.slope.angle_rad
        if delta == 0.0:
            return x
        self.slope.angle_rad = new
        self.kinks += 1
        step_m = self.rw_m * delta
        self.s0_m += step_m               # the axle has not moved: d has
        x = list(x)
        x[0] += step_m * self.d_per_m
        x[1] += step_m * self.d_per_m
        x[2] += delta
        return x

    def force(self, x):
        """The extra generalized force at x (5, the model's units), or None on a flat floor."""
        return None if self.slope is None else self.slope.at(x)
