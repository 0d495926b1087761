"""What the owner's experiments see of the robot: its links as rigid bodies about the joints.

The model's links are rods stacked on the axle (hostsim.model.equations): link i has mass m_i,
its centre of mass l_i above its lower joint, its inertia J_i about that centre, and the next
joint 2 l_i above the lower one. With the joints held straight, the parts above a joint are one
rigid body, and two experiments measure such bodies (docs/your-robot.md):

- the **joint swing** (link 1 held, one joint motor swings what it carries): the
  joint's *lever* ``a_j``, the first moment about the joint of everything above it (its gravity
  torque is g a_j sin(angle)), and its inertia ``b_j`` about the joint (the rotor's not
  included):

      a3 = m3 l3                           b3 = J3 + m3 l3^2
      a2 = m2 l2 + m3 (2 l2 + l3)          b2 = J2 + m2 l2^2 + J3 + m3 (2 l2 + l3)^2

- the **fall** (joints held, let go): the whole robot's lever about the axle
  ``a1 = M h = m1 l1 + m2 (2 l1 + l2) + m3 (2 l1 + 2 l2 + l3)``, its inertia about the axle
  ``I_a``, and the *fall pole* ``sqrt(g M h / I_roll)``: how fast the tilt grows, e^(pole t),
  when the robot rolls over its wheels as one rigid body (I_roll = I_a + 2 M h R_w + A, the
  inertia about the wheels' contact with the floor, A = (M + 2 m_w) R_w^2 + 2 J_w). It is what
  the fall test pins whatever the wheels do (tipbot_fw.bodyfit: the tilt's momentum balance,
  in which the wheel motors' torques cancel).

``lever_m`` ("m l per link") below are these levers, joint by joint: the gravity torque each
joint (the axle for link 1) must hold. The product m_i l_i of one link alone is not what a
swing or fall measures (link 2's lever a2 carries link 3's mass at its end), so it is given
apart (``link_products``).
"""
import math

from tipbot_fw import bodyfit

LINKS = (1, 2, 3)


def heights(p):
    """Centre-of-mass heights of links 1-3 above the axle, joints straight (m)."""
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    return (l1, 2 * l1 + l2, 2 * l1 + 2 * l2 + l3)


def levers(p):
    """(a1, a2, a3): the first moment (kg m) about the axle, joint 2 and joint 3 of everything
    above it, joints straight (module docstring)."""
    m1, m2, m3 = p["m1_kg"], p["m2_kg"], p["m3_kg"]
    l1, l2, l3 = p["l1_m"], p["l2_m"], p["l3_m"]
    a3 = m3 * l3
    a2 = m2 * l2 + m3 * (2 * l2 + l3)
    return (m1 * l1 + (m2 + m3) * 2 * l1 + a2, a2, a3)


def link_products(p):
    """(m1 l1, m2 l2, m3 l3) of each link alone."""
    return tuple(p["m%d_kg" % i] * p["l%d_m" % i] for i in LINKS)


def joint_inertias(p):
    """(I_a, b2, b3): inertia (kg m^2) about the axle, joint 2 and joint 3 of everything above
    it, joints straight, without the rotors."""
    m2, m3 = p["m2_kg"], p["m3_kg"]
    j2, j3 = p["j2_kg_m2"], p["j3_kg_m2"]
    l2, l3 = p["l2_m"], p["l3_m"]
    b3 = j3 + m3 * l3 ** 2
    b2 = j2 + m2 * l2 ** 2 + j3 + m3 * (2 * l2 + l3) ** 2
    i_a = sum(p["j%d_kg_m2" % i] + p["m%d_kg" % i] * h ** 2 for i, h in zip(LINKS, heights(p)))
    return (i_a, b2, b3)


# A = (M + 2 m_w) R_w^2 + 2 J_w (kg m^2): what the rolling adds about the contact point (the
# brick's pre-flight check needs it too)
wheel_term = bodyfit.wheel_term


def rolling_inertia(p):
    """I_roll: the joints-straight robot's inertia about the wheels' contact with the floor."""
    return joint_inertias(p)[0] + 2 * levers(p)[0] * p["rw_m"] + wheel_term(p)


def fall_pole(p):
    """The fall test's pole (1/s): sqrt(g M h / I_roll) (module docstring)."""
    return math.sqrt(p["g_m_s2"] * levers(p)[0] / rolling_inertia(p))


def summary(p):
    """The quantities the experiments measure, by name (SI)."""
    a = levers(p)
    i = joint_inertias(p)
    return {"fall_pole_1_s": fall_pole(p), "lever_kg_m": list(a), "inertia_kg_m2": list(i),
            "link_products_kg_m": list(link_products(p)), "wheel_term_kg_m2": wheel_term(p)}
