"""The robot's vocabulary: the names every part of tipbot speaks in, defined once.

The state, the inputs, what the sensors measure, the Kalman filter's extra states, the motors'
roles, the bits of a log row's flags and the versions of the files the firmware reads and
writes (docs/architecture.md, "State, input, measurement"). Standard library only and no
imports of tipbot_fw: every room of the firmware and the host may import it.
"""

# x = [d_r, d_l, th1, th2, th3, and their rates] (SI)
STATE_NAMES = ('d_r', 'd_l', 'th1', 'th2', 'th3', 'd_r_dot', 'd_l_dot', 'th1_dot', 'th2_dot', 'th3_dot')
STATE_UNITS = ('m', 'm', 'rad', 'rad', 'rad', 'm/s', 'm/s', 'rad/s', 'rad/s', 'rad/s')
N_STATES = len(STATE_NAMES)

# u = [u_r, u_l, u_th1, u_th2, u_th3] (V); INPUTS are the short names a column carries after its
# prefix (u_r, w_r, u_cmd_r, ...)
INPUTS = ('r', 'l', 'th1', 'th2', 'th3')
INPUT_NAMES = tuple('u_' + i for i in INPUTS)
N_INPUTS = len(INPUTS)
# The motors' inputs (a list: it indexes numpy arrays' columns); link 1 has no motor
ACTUATED_INPUTS = [0, 1, 3, 4]
UNUSED_INPUT = 2
ACTUATED = tuple(INPUTS[i] for i in ACTUATED_INPUTS)

# The motors, in the order of ACTUATED_INPUTS (the configuration's ports and polarities)
MOTOR_ROLES = ('right_wheel', 'left_wheel', 'joint2', 'joint3')

# What the sensors measure (the Kalman filter's m, SI): the wheel encoders relative to link 1,
# the joint encoders, the gyro's rate
MEASUREMENT_NAMES = ('phi_r', 'phi_l', 'th2', 'th3', 'gyro')
MEASUREMENT_UNITS = ('rad', 'rad', 'rad', 'rad', 'rad/s')

# The Kalman filter's states after x: the input disturbances of the disturbed inputs (V), the
# gyro's bias (rad/s), then, where a design has them, the law's integrators of the wheel
# positions (m s; tipbot_fw.cores.kalman, "Integral action")
DISTURBANCE_NAMES = tuple('w_' + a for a in ACTUATED)
GYRO_BIAS = 'gyro_bias'
INTEGRATOR_NAMES = ('z_r', 'z_l')


def integrator_count(state_names):
    """How many of a Kalman block's states are the law's integrators (the last ones): 0 or 2."""
    return len(INTEGRATOR_NAMES) if tuple(state_names[-len(INTEGRATOR_NAMES):]) == INTEGRATOR_NAMES else 0


# A log row's flags (docs/log-format.md)
FLAG_BITS = {
    'sat_r': 1, 'sat_l': 2, 'sat_th2': 4, 'sat_th3': 8,   # duty limited (u_max_v or +-100 %)
    'overrun': 16,      # this tick's work ended after the next release
    'fall': 32,         # |th1| beyond limits.th1_rad: motors stopped in this tick
    'joint_limit': 64,  # |th2| or |th3| beyond its limit: motors stopped in this tick
}
SATURATION_BITS = 1 | 2 | 4 | 8
STOP_FLAGS = FLAG_BITS['fall'] | FLAG_BITS['joint_limit']
# The bits from SKIP_SHIFT on: the whole periods the loop missed after this tick (a stall), which
# the core predicted through (its skip(); the replay does the same)
SKIP_SHIFT = 7
SKIP_MAX = (1 << 20) - 1
# After this tick the loop kept the law's integrators within their limit (KalmanCore.wind_down),
# which the replay does at the same place; above the skipped periods' bits
WOUND_DOWN = 1 << 27

# Versions of the files: the gains file's schema (the firmware refuses any other) and the log
# container's format (its reader reads this one and the one before)
GAINS_SCHEMA_VERSION = 2
LOG_FORMAT_VERSION = 2
