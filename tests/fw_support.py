"""Shared fixtures for the tests/test_fw_*.py firmware tests (host side: numpy + scipy).

A synthetic 10-state robot-like plant (d_r, d_l, th1, th2, th3 and rates; th1 unstable, link 1
unactuated), its gains file designed the way docs/architecture.md describes (LQR, the robust
detector of Section 6 with (L2 C - I) E = 0, G_w, K_w), and a lock-step simulation that drives
MemoryDevices from the plant whenever the loop sleeps on a VirtualClock.
"""
import json
import math

import numpy as np
import scipy.linalg

from hostsim.model.kalman import design_kalman
from tipbot_fw.config import config_from_overrides
from tipbot_fw.cores.kalman_design import spectral_radius
from tipbot_fw.gains import gains_from_dict
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.vocabulary import (ACTUATED_INPUTS, GAINS_SCHEMA_VERSION, INPUT_NAMES, N_INPUTS, STATE_NAMES,
                                  STATE_UNITS, UNUSED_INPUT)

TS = 0.005
R_W = 0.034
CM_SCALE = np.array([100.0, 100.0, 1, 1, 1, 100.0, 100.0, 1, 1, 1])   # x_cm = S x_SI


def plant(ts=TS):
    """Discrete (ZOH) A, B in SI of a linear three-link robot: gravity makes th1 unstable, the
    wheel motors push d and react on th1, the joint motors drive th2, th3 and react on th1."""
    G = np.array([[0, 0, -2.0, 0.5, 0.2],
                  [0, 0, -2.0, 0.5, 0.2],
                  [0, 0, 40.0, -6.0, -2.0],
                  [0, 0, -30.0, 10.0, 3.0],
                  [0, 0, 5.0, -8.0, 6.0]])
    D = -np.diag([8.0, 8.0, 0.3, 4.0, 6.0])
    Bm = np.array([[2.0, 0.1, 0, 0.2, 0.05],
                   [0.1, 2.0, 0, 0.2, 0.05],
                   [-8.0, -8.0, 0, -3.0, -1.0],
                   [4.0, 4.0, 0, 25.0, -4.0],
                   [-1.0, -1.0, 0, -6.0, 40.0]])
    Ac = np.block([[np.zeros((5, 5)), np.eye(5)], [G, D]])
    Bc = np.vstack([np.zeros((5, 5)), Bm])
    big = np.zeros((15, 15))
    big[:10, :10] = Ac * ts
    big[:10, 10:] = Bc * ts
    e = scipy.linalg.expm(big)
    return e[:10, :10], e[:10, 10:]


def gains_doc(ts=TS, u_max_v=7.6, detector_pole=0.2):
    """A valid gains document (SI units) for plant(ts): the LQR (scipy's DARE) and
    synthetic_gains_doc's recipe for the rest."""
    A, B = plant(ts)
    act = ACTUATED_INPUTS
    Ba = B[:, act]
    Q = np.diag([50.0, 50.0, 2000.0, 20.0, 20.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    R = np.diag([1.0, 1.0, 1.0, 1.0, 1.0])
    Ra = R[np.ix_(act, act)]
    P = scipy.linalg.solve_discrete_are(A, Ba, Q, Ra)
    K = np.zeros((5, 10))
    K[act, :] = np.linalg.solve(Ra + Ba.T.dot(P).dot(Ba), Ba.T.dot(P).dot(A))
    return synthetic_gains_doc(A, B, K, ts, Q=Q, R=R, u_max_v=u_max_v, detector_pole=detector_pole,
                               generator='tests/fw_support.py',
                               parameters={'wheel_radius_m': R_W}, parameters_sha256='0' * 64,
                               model_options={'synthetic': True})


def synthetic_gains_doc(A, B, K, ts_s, Q=None, R=None, u_max_v=7.6, detector_pole=0.2,
                        state_units=None, model_variant='physical', generator='synthetic', **extra):
    """A schema-2 gains document around a model (A, B) and a stabilizing gain K (SI): the detector
    of Section 6 with G_w = B_a^+ (so L2 = E G_w projects on range(E): (L2 C - I) E = 0),
    L1 = Abar - detector_pole I (so Abar - L1 C = detector_pole I), K_w = I on the actuated
    inputs (it cancels an input disturbance), and the Kalman block the host designs for it
    (hostsim.model.kalman.design_kalman, its noise figures, R_W). extra: further fields."""
    n = A.shape[0]
    Ba = B[:, ACTUATED_INPUTS]
    G = np.zeros((N_INPUTS, n))
    G[ACTUATED_INPUTS, :] = np.linalg.pinv(Ba)
    L2 = Ba.dot(G[ACTUATED_INPUTS, :])
    L1 = (np.eye(n) - L2).dot(A) - detector_pole * np.eye(n)
    K_w = np.diag([0.0 if i == UNUSED_INPUT else 1.0 for i in range(N_INPUTS)])
    kalman = design_kalman(A, B, K, K_w, R_W, ts_s).document()
    doc = {
        'schema_version': GAINS_SCHEMA_VERSION, 'model_variant': model_variant, 'ts_s': ts_s,
        'state_names': list(STATE_NAMES), 'state_units': list(STATE_UNITS if state_units is None else state_units),
        'input_names': list(INPUT_NAMES), 'input_units': ['V'] * N_INPUTS,
        'actuated_inputs': list(ACTUATED_INPUTS),
        'A': A.tolist(), 'B': B.tolist(), 'C': np.eye(n).tolist(), 'E': B.tolist(),
        'K': K.tolist(), 'K_w': K_w.tolist(), 'L1': L1.tolist(), 'L2': L2.tolist(),
        'G_w': G.tolist(), 'detector_eigenvalues': [detector_pole] * n,
        'closed_loop_spectral_radius': spectral_radius(A - B.dot(K)),
        'Q': (np.eye(n) if Q is None else Q).tolist(), 'R': (np.eye(N_INPUTS) if R is None else R).tolist(),
        'u_max_v': u_max_v, 'parameters': {}, 'parameters_sha256': '', 'model_options': {},
        'generator': generator,
        'kalman': json.loads(json.dumps(kalman, default=lambda a: a.tolist())),
    }
    doc.update(extra)
    return doc


def to_cm(doc):
    """The same gains with d and its rate in cm and cm/s (x_cm = S x_SI)."""
    S = np.diag(CM_SCALE)
    Si = np.diag(1.0 / CM_SCALE)
    m = {k: np.array(doc[k]) for k in ('A', 'B', 'E', 'K', 'L1', 'L2', 'G_w', 'Q')}
    out = json.loads(json.dumps(doc))
    out['state_units'] = ['cm', 'cm', 'rad', 'rad', 'rad', 'cm/s', 'cm/s', 'rad/s', 'rad/s', 'rad/s']
    out['model_variant'] = 'paper'
    out['A'] = S.dot(m['A']).dot(Si).tolist()
    out['B'] = S.dot(m['B']).tolist()
    out['E'] = S.dot(m['E']).tolist()
    out['K'] = m['K'].dot(Si).tolist()
    out['L1'] = S.dot(m['L1']).dot(Si).tolist()
    out['L2'] = S.dot(m['L2']).dot(Si).tolist()
    out['G_w'] = m['G_w'].dot(Si).tolist()
    out['Q'] = Si.dot(m['Q']).dot(Si).tolist()
    return out


def write_json(path, doc):
    path = str(path)
    with open(path, 'w') as f:
        json.dump(doc, f)
    return path


def load(doc=None, **kw):
    return gains_from_dict(gains_doc(**kw) if doc is None else doc, '<test gains>', 'test-sha')


def fw_config(**overrides):
    """Defaults with a short calibration and no SCHED_FIFO (never in a test process)."""
    base = {'realtime_priority': 0, 'gyro_calibration': {'duration_s': 0.1}}
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            base[key] = dict(base[key], **value)
        else:
            base[key] = value
    return config_from_overrides(base, '<test config>')


class Lockstep(object):
    """Plant + MemoryDevices + VirtualClock in lock-step: each sleep of the loop advances the
    plant one period with the duties the devices hold (none before the first write: the robot
    is held still during calibration), then sets the devices' raw readings from the new state.

    Sensors: 1-count encoders (360 per turn, reading enc_zero at zero), wheel encoders relative
    to link 1, gyro rate in integer deg/s plus `gyro_bias_dps`, gyro angle in integer degrees.
    """

    def __init__(self, x0=None, battery_v=8.0, gyro_bias_dps=0, disturbance=None, enc_zero=(0, 0, 0, 0)):
        self.A, self.B = plant()
        self.enc_zero = enc_zero
        self.x = np.zeros(10) if x0 is None else np.array(x0, dtype=float)
        self.bias = gyro_bias_dps
        self.w = np.zeros(5) if disturbance is None else np.array(disturbance, dtype=float)
        self.dev = MemoryDevices(battery_v=battery_v)
        self.clock = VirtualClock(on_sleep=self.on_sleep)
        self.steps = 0
        self.on_step = None     # called with (self) after each plant step
        self.publish()

    def applied_u(self):
        d = self.dev.duties   # signed for the motors; all polarities are +1 in these tests
        return np.array([d[0], d[1], 0, d[2], d[3]], dtype=float) * self.dev.battery_v / 100.0

    def on_sleep(self, t_from, t_to):
        if self.dev.write_calls == 0:
            return
        self.x = self.A.dot(self.x) + self.B.dot(self.applied_u() + self.w)
        self.steps += 1
        self.publish()
        if self.on_step is not None:
            self.on_step(self)

    def publish(self):
        x = self.x
        k = 360.0 / (2.0 * math.pi)
        phi_r = x[0] / R_W - x[2]
        phi_l = x[1] / R_W - x[2]
        z = self.enc_zero
        self.dev.enc = (int(round(phi_r * k)) + z[0], int(round(phi_l * k)) + z[1],
                        int(round(x[3] * k)) + z[2], int(round(x[4] * k)) + z[3])
        self.dev.gyro = (int(round(math.degrees(x[2]))), int(round(math.degrees(x[7]))) + self.bias)


class TickCounter(object):
    """on_sleep hook of a VirtualClock: counts loop ticks (sleeps after the first write) and
    runs `action(n)`."""

    def __init__(self, dev, action):
        self.dev, self.action, self.n = dev, action, 0

    def __call__(self, t_from, t_to):
        if self.dev.write_calls:
            self.n += 1
            self.action(self.n)


def moving_readings(polarity=1):
    """A MemoryDevices source whose readings move every tick (so every logged value differs from
    tick to tick), by steps the hardware can make (tipbot_fw.guard.plausibility: a few counts a tick)."""
    ticks = iter(range(10 ** 6))
    return lambda: (lambda n: ((polarity * 3 * n, -n, n % 12, n % 7), (n // 50, (n % 5) - 2)))(next(ticks))
