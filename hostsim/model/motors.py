"""The paper's DC motors (Table 2) and the parameters of a motor as Section 4 models it.

Output-shaft quantities, SI: J w' = Km i - beta w - Tc sgn(w), i = (u - Ke w) / Ra (inductance
neglected). The identification on the host (hostsim.logs.identify) compares what it finds
with these; the simulated motor (hostsim.sim.motor_sim) runs them.
"""
import math
from collections import namedtuple

_Params = namedtuple("MotorParams", "beta_nm_s ke_v_s km_nm_a ra_ohm jm_kg_m2 coulomb_nm")


class MotorParams(_Params):
    """A motor's parameters (SI, output shaft). phi, alpha: G(s) = phi / (alpha s + 1) from
    volts to rad/s (Section 4); tau_coast_s: the run-down's time constant Jm / beta."""

    def __new__(cls, beta_nm_s, ke_v_s, km_nm_a, ra_ohm, jm_kg_m2, coulomb_nm=0.0):
        return _Params.__new__(cls, float(beta_nm_s), float(ke_v_s), float(km_nm_a), float(ra_ohm),
                               float(jm_kg_m2), float(coulomb_nm))

    @property
    def phi(self):
        return self.km_nm_a / (self.ra_ohm * self.beta_nm_s + self.ke_v_s * self.km_nm_a)

    @property
    def alpha(self):
        return self.ra_ohm * self.jm_kg_m2 / (self.ra_ohm * self.beta_nm_s + self.ke_v_s * self.km_nm_a)

    @property
    def tau_coast_s(self):
        return self.jm_kg_m2 / self.beta_nm_s if self.beta_nm_s > 0 else math.inf


#: Table 2 of the paper (beta, Ke, Km, Ra, Jm). Motors 1-4 are EV3 large motors, motor 5 the
#: medium one (th3 joint); motor 4 is not used on the robot.
TABLE2 = {
    1: MotorParams(0.000486, 0.43798, 0.27063, 8.34, 0.00101),
    2: MotorParams(0.000577, 0.35732, 0.24105, 9.01, 0.00125),
    3: MotorParams(0.000458, 0.44706, 0.31059, 8.74, 0.00123),
    4: MotorParams(0.000662, 0.44535, 0.30670, 8.47, 0.00118),
    5: MotorParams(0.000206, 0.27480, 0.17340, 12.22, 0.00011),
}
#: Table 2's printed G(s): (phi, alpha) per motor.
TABLE2_G = {1: (2.207, 0.0688), 2: (2.639, 0.1235), 3: (2.174, 0.0755), 4: (2.1563, 0.0707), 5: (3.45, 0.028)}
#: ev3dev driver of each Table 2 motor.
TABLE2_DRIVER = {1: "lego-ev3-l-motor", 2: "lego-ev3-l-motor", 3: "lego-ev3-l-motor", 4: "lego-ev3-l-motor",
                 5: "lego-ev3-m-motor"}
#: Table 2 motor of each role (shared/paper/README.md), and of each ev3dev driver when a log
#: names no role.
ROLE_MOTOR = {"right_wheel": 1, "left_wheel": 2, "joint2": 3, "joint3": 5}
DRIVER_MOTOR = {"lego-ev3-l-motor": 1, "lego-ev3-m-motor": 5}
