"""The firmware's default estimator: a steady-state Kalman filter on the gains' discrete model.

It measures what the sensors measure and carries, beside the robot's state, the input
disturbances and the gyro bias, so that the compensation ``u = -K x^ - K_w w^`` and the bias
come out of one filter (docs/architecture.md, "Kalman filter").

Augmented model, SI, one step of the period ts (x_a has 13 entries):

    x_a = [x (10), w_r, w_l (volts on the wheels' inputs), b (gyro bias, rad/s)]
    x_a+ = A_a x_a + B_a u + noise       A_a = [[A, B_wheels, 0], [0, I, 0], [0, 0, 1]], B_a = [B_act; 0; 0]
    m    = C_a x_a + noise               m = [phi_r, phi_l, th2, th3, gyro]

phi_r, phi_l are the wheel encoders' angles, which are RELATIVE to link 1 (the motors sit on
it): phi = d / R_w - th1; th2, th3 the joint encoders; gyro = th1' + b. So the filter sees no
state directly but the joint angles: the tilt and its bias are told apart by the dynamics (a
lean the model cannot explain without the base accelerating, which the wheel encoders see; a
bias error instead makes the estimated tilt drift while nothing else moves: the pair is
observable, rank 13, and the filter's error decays whatever its start: tests/test_fw_kalman.py
shows a wrong calibrated bias found and a wrong start tilt not learnt as a bias).

Filter, in the "current" (filtered) form: the estimate of tick k uses the reading of tick k,
and the model is fed the input actually APPLIED (after rounding and saturation):

    x^_k  = x-_k + L (m_k - C_a x-_k)          x-_k = A_a x^_{k-1} + B_a u_{k-1}
    u_k   = -K_a x^_k,   K_a = [K_act, K_w_act (the wheels' columns), 0]

L is the steady-state gain of the discrete Riccati equation (scipy) with the noise settings of
``NoiseSettings``; each one is derived from a published hardware fact or a stated physical
rate of change, recorded with its reason in the gains file.
"""
import dataclasses
import math
from typing import Optional

import numpy as np
import scipy.linalg

from hostsim.errors import DesignError
from hostsim.model import design
from tipbot_fw.cores import kalman_design as fw_design
from tipbot_fw.cores.kalman_design import law_gain, spectral_radius  # noqa: F401  (the host's one of each)
from tipbot_fw.vocabulary import (ACTUATED, ACTUATED_INPUTS, DISTURBANCE_NAMES, GYRO_BIAS, INTEGRATOR_NAMES,
                                  MEASUREMENT_NAMES, MEASUREMENT_UNITS, N_STATES, STATE_NAMES, STATE_UNITS)

N_X = N_STATES
N_U = len(ACTUATED_INPUTS)
# The input disturbances the filter estimates: the wheels' (module docstring of NoiseSettings).
DISTURBANCE_INPUTS = (0, 1)          # indices into the actuated inputs (u_r, u_l, u_th2, u_th3)
WHEEL_INPUTS = (0, 1)
# The designs that are ours (with the law's integrators) estimate joint 2's too, for the filter's
# sake only: the law does not compensate it (hostsim.model.gains.law_design; NoiseSettings). Joint 3's
# would cost the tick another 1,000 ARMv5 instructions (two more rows and columns of the product)
# for a few mrad: its Medium motor has almost no play, and the joint weight keeps it stiff.
INTEGRAL_DISTURBANCE_INPUTS = (0, 1, 2)
N_M = len(MEASUREMENT_NAMES)
ACTUATED_NAMES = tuple("u_" + a for a in ACTUATED)
# Multipliers tried, in order, on the filter's input noise (NoiseSettings.input_noise_scale):
# fictitious input noise is the classic way to give a Kalman filter's loop back the robustness of
# the state feedback it serves (loop transfer recovery), at the cost of noisier estimates.
INPUT_NOISE_LADDER = (1.0, 2.0, 3.0, 4.0)
DEG = math.pi / 180.0
ENCODER_COUNTS_PER_ROT = 360


# The unit of the law's integrators of the wheel positions (tipbot_fw.vocabulary.INTEGRATOR_NAMES,
# after the filter's states where a design has them: tipbot_fw.cores.kalman, "Integral action").
INTEGRAL_UNIT = "m s"
# The integrators' authority: at their limit they ask at most this share of u_max of a motor (the
# rest for balancing and driving); a tilt estimate 0.02 rad off (a start a degree off upright)
# needs about a third of it on the committed physical design.
INTEGRAL_SHARE = 0.5


def state_names(dist_inputs=DISTURBANCE_INPUTS, integral=False):
    return STATE_NAMES + tuple(DISTURBANCE_NAMES[i] for i in dist_inputs) + (GYRO_BIAS,) + (INTEGRATOR_NAMES if integral else ())


def state_units(dist_inputs=DISTURBANCE_INPUTS, integral=False):
    return STATE_UNITS + ("V",) * len(dist_inputs) + ("rad/s",) + ((INTEGRAL_UNIT,) * len(INTEGRATOR_NAMES) if integral else ())


@dataclasses.dataclass(frozen=True)
class NoiseSettings:
    """The filter's noise model. Every value is a physical figure (../shared/ev3-hardware.md);
    the methods turn them into the per-tick matrices.

    Measurement (white, per reading):
    - encoders: one count of quantization, 2 pi / 360 rad, uniform error: count^2 / 12.
      Backlash (about 3 deg at a Large motor's output) is no white noise but free play in the
      drive; widening the encoders' variance for it made every run worse (the estimate then
      leans on the noisier gyro), so it is left to the robustness checks.
    - gyro: integer deg/s readings (1/12 (deg/s)^2 of quantization) plus what else makes the
      reading differ from the rate at the tick, ``gyro_noise_dps`` = 1 deg/s, in quadrature:
      the sensor's noise (0.5 deg/s, the top of our Monte Carlo's), its lag (a 10 ms lag on the
      ~1 rad/s^2 of balancing: 0.6 deg/s) and its scale error (about 2 %, on rates up to
      20 deg/s: 0.4 deg/s) (../shared/ev3-hardware.md). The readings also stick and move in
      steps of about 6 deg/s while turning (6/sqrt(12) = 1.7 deg/s): 1 deg/s is not pessimistic.
    Process:
    - input noise, volts on each actuated input, white per tick: what the model does not know
      about the motors from one tick to the next, chiefly Coulomb friction, which flips with
      the direction of turn: 4 % duty on a Large motor, 10 % on the Medium one, at 8 V
      0.32 V (wheels, joint 2) and 0.8 V (joint 3). The design multiplies these by
      ``input_noise_scale``, the first step of INPUT_NOISE_LADDER whose loop holds every plant
      of UncertaintySet (hostsim.model.gains.robust_design): fictitious input noise is the
      classic way to give an estimator-based loop the robustness of the state feedback it
      serves (loop transfer recovery); a model-trusting filter loses it.
    - input disturbances, random walk, on the wheels (``DISTURBANCE_INPUTS``): how fast a
      disturbance that persists changes: a slope, a friction level that settles, the battery
      sagging under a sustained load, a hand: by about 1 V over 10 s, i.e. 0.1 V^2/s (faster
      changes are the input noise's). Faster rates (1 V^2/s) made the loop lose the other
      model variant with 4 ms of input delay. The wheels' estimates keep the paper's
      disturbance rejection (Sections 7, 8 and Appendix D disturb the wheels).
    - joint 2's input disturbance (``INTEGRAL_DISTURBANCE_INPUTS``, in the designs with
      integral action), random walk, ``joint_disturbance_rate_v2_per_s`` = 3e-4 V^2/s. What
      holds joint 2 is the load of links 2 and 3 (a payload, a slope, a bent pose: tenths of a
      volt) and its motor's Coulomb friction (0.32 V), which flips with the direction of
      turn. Without an estimate of it the filter explains joint 2's holding
      voltage (links 2 and 3 held against gravity, its gears pressed to one side of their 3
      degrees of play, so that its encoder reads 1.5-2 degrees off) with a wrong tilt (the
      realistic brick: th1^ 0.015-0.023 rad off, joint 2 held 0.075 rad bent).
      The estimate serves the filter only: the law does not compensate it (law_design), so
      no integrator is closed around the joint's friction and backlash, which hunts (stick,
      wind up, break away, overshoot): cancelling both joints' estimates, joint 2 wandered
      +-0.04 rad over seconds on the realistic brick; at the wheels' rate, 0.1 V^2/s, link 3
      swung +-0.13 rad at 0.6 Hz. Slow (time constants of seconds, slower than the balancing
      and the backlash's 1-3 Hz cycle), it follows a load and the friction's mean, not its
      flips (docs/architecture.md, "Joint 2's disturbance").
    - gyro bias b, random walk: the EV3 gyro drifts with temperature and time; our design case,
      a drift of 0.01 deg/s per second, is a change of (0.01 deg/s)^2 per second.
    - the wheels' acceleration, white per tick, ``wheel_accel_noise_m_s2`` = 0.2 m/s^2: what
      the model does not know about where the wheels roll: their radius (which tyre, how
      compressed: a few percent, and 20 % with the wrong wheel), the floor (slip, bumps, a
      change of slope): 20 % of the ~1 m/s^2 of balancing. Without it a wheel radius 20 % off
      the gains' leaves the loop undamped; with it the estimate of the lean relies less on the
      wheels' exact acceleration.
    """
    encoder_count_rad: float = 2.0 * math.pi / ENCODER_COUNTS_PER_ROT
    gyro_resolution_dps: float = 1.0
    gyro_noise_dps: float = 1.0
    input_noise_v: tuple = (0.32, 0.32, 0.32, 0.8)
    disturbance_inputs: tuple = DISTURBANCE_INPUTS
    disturbance_rate_v2_per_s: float = 0.1
    joint_disturbance_rate_v2_per_s: float = 3e-4
    bias_drift_dps_per_s: float = 0.01
    input_noise_scale: float = 1.0      # set by the design's robustness ladder (INPUT_NOISE_LADDER)
    wheel_accel_noise_m_s2: float = 0.2

    @property
    def n_states(self):
        return N_X + len(self.disturbance_inputs) + 1

    def measurement_covariance(self):
        r_enc = self.encoder_count_rad ** 2 / 12.0
        r_gyro = (self.gyro_resolution_dps ** 2 / 12.0 + self.gyro_noise_dps ** 2) * DEG ** 2
        return np.diag([r_enc] * 4 + [r_gyro])

    def disturbance_rates(self):
        """The random walks' rates (V^2/s) of the estimated disturbances, in their order."""
        return [self.disturbance_rate_v2_per_s if i in WHEEL_INPUTS else self.joint_disturbance_rate_v2_per_s
                for i in self.disturbance_inputs]

    def process_covariance(self, b_act, ts_s):
        """Per-tick covariance of the augmented state's noise (n x n)."""
        n, nw = self.n_states, len(self.disturbance_inputs)
        q = np.zeros((n, n))
        q[:N_X, :N_X] = b_act @ np.diag(np.square(np.asarray(self.input_noise_v) * self.input_noise_scale)) @ b_act.T
        q[N_X:N_X + nw, N_X:N_X + nw] = np.diag(self.disturbance_rates()) * ts_s
        q[n - 1, n - 1] = (self.bias_drift_dps_per_s * DEG) ** 2 * ts_s
        for i in (5, 6):
            q[i, i] += (self.wheel_accel_noise_m_s2 * ts_s) ** 2
        return q

    def provenance(self):
        """The settings with units and reasons, for the gains file."""
        r = self.measurement_covariance()
        return {
            "encoder_count_rad": {"value": self.encoder_count_rad, "unit": "rad", "variance_rad2": r[0, 0],
                                  "why": "one count of 360 per turn, uniform quantization error: count^2/12"},
            "gyro_resolution_dps": {"value": self.gyro_resolution_dps, "unit": "deg/s",
                                    "why": "GYRO-G&A reports integer deg/s: 1/12 (deg/s)^2"},
            "gyro_noise_dps": {"value": self.gyro_noise_dps, "unit": "deg/s", "variance_rad2_s2": r[4, 4],
                               "why": "in quadrature: sensor noise 0.5 deg/s (the top of the Monte Carlo's), a "
                                      "10 ms lag on ~1 rad/s^2 of balancing 0.6 deg/s, a 2 % scale error on rates "
                                      "up to 20 deg/s 0.4 deg/s; readings also step by ~6 deg/s (1.7 deg/s rms)"},
            "input_noise_v": {"value": list(self.input_noise_v), "unit": "V on u_r, u_l, u_th2, u_th3, white per tick",
                              "why": "Coulomb friction, which flips with the direction of turn: 4 % (Large) and "
                                     "10 % (Medium, joint 3) duty at 8 V"},
            "input_noise_scale": {"value": self.input_noise_scale,
                                  "why": "the first multiplier of the input noise whose loop holds both model "
                                         "variants with 0-4 ms of input delay and +-20 % motor gain (loop "
                                         "transfer recovery; robust_to_models)"},
            "disturbance_inputs": {"value": [ACTUATED_NAMES[i] for i in self.disturbance_inputs],
                                   "why": "the wheels' (a slope's pull, a hand, the battery), compensated by the "
                                          "law; in our designs joint 2's too (a load, the friction's mean), for "
                                          "the filter only: else its load reads as a wrong tilt"},
            "joint_disturbance_rate_v2_per_s": {"value": self.joint_disturbance_rate_v2_per_s, "unit": "V^2/s",
                                                "why": "slow (time constants of seconds): the estimate follows a "
                                                       "load and the friction's mean, not its flips"},
            "disturbance_rate_v2_per_s": {"value": self.disturbance_rate_v2_per_s, "unit": "V^2/s",
                                          "why": "a persistent disturbance (slope, friction level, battery sag, "
                                                 "a hand) changes by about 1 V over 10 s"},
            "wheel_accel_noise_m_s2": {"value": self.wheel_accel_noise_m_s2, "unit": "m/s^2, white per tick",
                                       "why": "the wheels' radius (tyre, compression; another wheel: 20 %) and the "
                                              "floor (slip, bumps, slope): 20 % of the ~1 m/s^2 of balancing"},
            "bias_drift_dps_per_s": {"value": self.bias_drift_dps_per_s, "unit": "deg/s per s",
                                     "why": "gyro drift with temperature and time, as a random walk of "
                                            "0.01 deg/s per second"},
        }




def augmented_model(a_si, b_si, rw_m, dist_inputs=DISTURBANCE_INPUTS):
    """(A_a, B_a, C_a) of the module docstring from the discrete model (SI)."""
    return fw_design.augmented_model(a_si, b_si[:, ACTUATED_INPUTS], rw_m, dist_inputs)


def observability_rank(aa, ca):
    n = aa.shape[0]
    o = np.vstack([ca @ np.linalg.matrix_power(aa, i) for i in range(n)])
    return int(np.linalg.matrix_rank(o))


def kalman_gain(aa, ca, qn, rn):
    """Steady-state gain of the filtered form and the prior / posterior covariances."""
    try:
        p = scipy.linalg.solve_discrete_are(aa.T, ca.T, qn, rn)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise DesignError("the filter's Riccati equation has no stabilizing solution: %s" % exc)
    s = ca @ p @ ca.T + rn
    gain = np.linalg.solve(s, ca @ p).T
    post = (np.eye(aa.shape[0]) - gain @ ca) @ p
    return gain, p, (post + post.T) / 2


@dataclasses.dataclass(frozen=True)
class IntegralLaw:
    """The law's integral action: K_z (4 x 2, V per m s of z_r, z_l, SI) and the integrators'
    limit (m s), from INTEGRAL_SHARE of u_max."""
    K_z: np.ndarray
    limit_m_s: float
    u_max_v: float

    def document(self):
        # (the text names the module as the committed gains files do: regenerated files stay identical;
        # the core is tipbot_fw/cores/kalman.py)
        return {"states": list(INTEGRATOR_NAMES), "limit_m_s": self.limit_m_s, "share_of_u_max": INTEGRAL_SHARE,
                "why": "z = integral of (d^ - d_ref) of each wheel (tipbot_fw.kalman, 'Integral action'); the "
                       "LQR's integral weight is the wheel position's over hostsim.model.gains.INTEGRAL_TIME_S; "
                       "each z is kept within limit_m_s, where both together ask %g of u_max = %g V of a motor "
                       "at most (anti-windup)" % (INTEGRAL_SHARE, self.u_max_v)}


def integral_law(k_z, u_max_v):
    """IntegralLaw of the integrators' gains K_z (4 x 2, SI) for a motor limit u_max_v."""
    k_z = np.asarray(k_z, dtype=float)
    worst = float(np.max(np.abs(k_z).sum(axis=1)))
    return IntegralLaw(K_z=k_z, limit_m_s=INTEGRAL_SHARE * u_max_v / worst, u_max_v=float(u_max_v))


def with_integrators(aa, ba, ca, gain, ts_s):
    """The filter's (A_a, B_a, C_a, L) with the law's integrators of the wheel positions after its
    states (tipbot_fw.cores.kalman, "Integral action"): z_k = z_{k-1} + ts d^_k, so A's and B's rows of
    z are ts times d's (the prediction d-_k), L's ts times d's (the update to d^_k), C blind to z."""
    a, b = design.integrator_model(aa, ba, ts_s)         # the LQR's model with its integrators
    c = np.hstack([ca, np.zeros((ca.shape[0], len(INTEGRATOR_NAMES)))])
    return a, b, c, design.integrator_model(aa, gain, ts_s)[1]


@dataclasses.dataclass(frozen=True)
class KalmanDesign:
    ts_s: float
    rw_m: float            # the wheel radius of C_a
    noise: NoiseSettings
    A: np.ndarray          # A_a (n x n)
    B: np.ndarray          # B_a (n x 4)
    C: np.ndarray          # C_a (5 x n)
    Q: np.ndarray          # process noise per tick (n x n)
    R: np.ndarray          # measurement noise (5 x 5)
    L: np.ndarray          # filter gain, filtered form (n x 5)
    P: np.ndarray          # steady-state prior covariance
    P_post: np.ndarray     # and posterior (the estimate's)
    K: np.ndarray          # K_a (4 x n)
    observability_rank: int
    integral: Optional[IntegralLaw] = None     # the law's integrators (after the filter's states)

    @property
    def n(self):
        return self.A.shape[0]

    @property
    def n_filter(self):
        """The filter's states (Q, P, P_post are of these; the integrators come after them)."""
        return self.Q.shape[0]

    @property
    def state_names(self):
        return state_names(self.noise.disturbance_inputs, self.integral is not None)

    @property
    def state_units(self):
        return state_units(self.noise.disturbance_inputs, self.integral is not None)

    @property
    def filter_eigenvalues(self):
        """Of the estimation error x - x^ (its dynamics (I - L C) A, of the filter's states)."""
        nf = self.n_filter
        return np.linalg.eigvals((np.eye(nf) - self.L[:nf] @ self.C[:, :nf]) @ self.A[:nf, :nf])

    def folded_law(self):
        """The tick as one matrix (tipbot_fw.cores.kalman): rows [u_k (4), xi_k (n)], columns
        [u_{k-1} (4, applied volts), xi_{k-1} (n), dphi_r, dphi_l, m_k (5, SI)]."""
        return fw_design.fold(self.A, self.B, self.C, self.L, self.K, self.rw_m, self.n - self.n_filter)

    def state_bounds(self):
        return [STATE_BOUNDS[name.split("_")[0] if name.startswith(("w_", "z_")) else name]
                for name in self.state_names]

    def document(self):
        """The gains file's `kalman` block (SI; docs/architecture.md)."""
        return {
            "state_names": list(self.state_names), "state_units": list(self.state_units),
            "measurement_names": list(MEASUREMENT_NAMES), "measurement_units": list(MEASUREMENT_UNITS),
            "wheel_radius_m": self.rw_m,
            "A": self.A, "B": self.B, "C": self.C, "L": self.L, "K": self.K, "Q": self.Q, "R": self.R,
            "law": {"M": self.folded_law(), "state_bounds": self.state_bounds(),
                    "rows": list(ACTUATED_NAMES) + ["xi_" + n for n in self.state_names],
                    "columns": list(ACTUATED_NAMES) + ["xi_" + n for n in self.state_names]
                    + ["dphi_r", "dphi_l"] + list(MEASUREMENT_NAMES),
                    "state_bounds_why": STATE_BOUNDS_WHY},
            "noise": self.noise.provenance(),
            "posterior_std": list(np.sqrt(np.diag(self.P_post))),
            "filter_eigenvalues_abs": sorted(float(abs(z)) for z in self.filter_eigenvalues),
            "observability_rank": self.observability_rank,
            **({} if self.integral is None else {"integral": self.integral.document()}),
        }


# Ranges of the carried state for the fixed-point law (tipbot_fw.cores.fixedpoint): far beyond what
# a standing robot reaches, so that no sum can overflow; their resolution is bound / 2^32.
STATE_BOUNDS = {"d_r": 1.0, "d_l": 1.0, "th1": 4.0, "th2": 4.0, "th3": 4.0, "d_r_dot": 20.0, "d_l_dot": 20.0,
                "th1_dot": 200.0, "th2_dot": 200.0, "th3_dot": 200.0, "w": 100.0, "gyro_bias": 1.0, "z": 2.0 ** 15}
STATE_BOUNDS_WHY = ("fixed-point ranges (resolution bound/2^32): xi_d = d - R_w phi is R_w th1 plus the "
                    "estimate's error (< 1 m); angles < 4 rad (the run stops at 0.6 / 1.2 rad); wheel speeds "
                    "< 20 m/s and rates < 200 rad/s (the motors reach 0.6 m/s and 30 rad/s, the gyro 7.7 rad/s); "
                    "disturbances < 100 V (the battery is 9 V); gyro bias < 1 rad/s (57 deg/s); integrators "
                    "< 2^15 m s (the loop keeps them within kalman.integral.limit_m_s once a second; within that "
                    "second they gain |d^ - d_ref| m s at most, less than the range below 16 km of error)")


def design_kalman(a_si, b_si, k_si, k_w, rw_m, ts_s, noise=None, integral=None):
    """The filter and the law for one model (SI) -> KalmanDesign; integral: the law's
    IntegralLaw (its integrators come after the filter's states), or None."""
    noise = NoiseSettings() if noise is None else noise
    aa, ba, ca = augmented_model(a_si, b_si, rw_m, noise.disturbance_inputs)
    rank = observability_rank(aa, ca)
    if rank < aa.shape[0]:
        raise DesignError("the augmented model is not observable from the sensors (rank %d < %d)"
                          % (rank, aa.shape[0]))
    qn = noise.process_covariance(ba[:N_X], ts_s)
    rn = noise.measurement_covariance()
    gain, p, post = kalman_gain(aa, ca, qn, rn)
    k_a = law_gain(k_si, k_w, noise.disturbance_inputs, None if integral is None else integral.K_z)
    if integral is not None:
        aa, ba, ca, gain = with_integrators(aa, ba, ca, gain, ts_s)
    return KalmanDesign(ts_s=float(ts_s), rw_m=float(rw_m), noise=noise, A=aa, B=ba, C=ca, Q=qn, R=rn,
                        L=gain, P=p, P_post=post, K=k_a, observability_rank=rank, integral=integral)


def delayed_plant(ac_si, bc_si, ts_s, delay_s):
    """The plant sampled at ts_s when each new input lands delay_s into the tick (the old one
    holds until then): x_{k+1} = A x_k + B1 u_k + B0 u_{k-1} (SI, all 5 inputs)."""
    n, m = bc_si.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = ac_si
    big[:n, n:] = bc_si

    def phi(t):
        e = scipy.linalg.expm(big * t)
        return e[:n, :n], e[:n, n:]
    a, b_full = phi(ts_s)
    a_rest, b_rest = phi(ts_s - delay_s)     # from the landing to the tick's end
    b1 = b_rest
    b0 = b_full - b_rest
    return a, b1, b0


def loop_matrix(kd, a, b1, b0, rw_m=None):
    """The loop of plant, filter and law, the plant given as delayed_plant()'s (A, B1, B0) (SI,
    5 inputs) and its wheel radius (default the filter's; another one is a scale error of the
    wheel encoders): state [x (10), u_{k-1} (4), x^ (n)]."""
    act = ACTUATED_INPUTS
    b1, b0 = b1[:, act], b0[:, act]
    n = kd.n
    ca_x = fw_design.measurement_matrix(n, kd.rw_m if rw_m is None else rw_m)[:, :N_X]
    ikc = np.eye(n) - kd.L @ kd.C
    # u_k = -K x^_k;  x_{k+1} = A x_k + B1 u_k + B0 u_{k-1};
    # x^_{k+1} = ikc (A_a x^_k + B_a u_k) + L C_x x_{k+1}
    big = np.zeros((N_X + N_U + n, N_X + N_U + n))
    xs, us, hs = slice(0, N_X), slice(N_X, N_X + N_U), slice(N_X + N_U, N_X + N_U + n)
    big[xs, xs] = a
    big[xs, us] = b0
    big[xs, hs] = -b1 @ kd.K
    big[us, hs] = -kd.K
    big[hs, xs] = kd.L @ ca_x @ a
    big[hs, us] = kd.L @ ca_x @ b0
    big[hs, hs] = ikc @ (kd.A - kd.B @ kd.K) - kd.L @ ca_x @ b1 @ kd.K
    return big


# Oscillations are judged above this frequency (slower modes are the estimates' own settling).
DAMPING_ABOVE_HZ = 0.5


def loop_margins(kd, a, b1, b0, rw_m=None):
    """(spectral radius, least damping ratio of the loop's modes above DAMPING_ABOVE_HZ)."""
    ev = np.linalg.eigvals(loop_matrix(kd, a, b1, b0, rw_m)).astype(complex)
    ev = ev[np.abs(ev) > 1e-12]
    s = np.log(ev) / kd.ts_s
    hz = np.abs(s.imag) / (2 * np.pi)
    zeta = -s.real / np.abs(s)
    fast = hz > DAMPING_ABOVE_HZ
    return float(np.max(np.abs(ev))), float(np.min(zeta[fast])) if fast.any() else 1.0


# The uncertainty a design must hold (hostsim.model.gains): both model variants (they bracket
# what is least certain about the drivetrain), the new duties landing 0-4 ms into the tick
# (five sysfs reads, the compute, then up to four writes: ../shared/ev3-hardware.md), the
# motors' gain 20 % off (battery sag under load, motor constants), and the wheels 20 % smaller
# or larger than the gains' R_w (another tyre: a scale error of the wheel encoders). Every mode
# of the loop must decay (time constant under 10 s: the gyro bias's own is ~7 s) and every
# oscillation above 0.5 Hz with a damping ratio of at least 0.05.
ROBUST_MODELS = ("paper", "physical")
ROBUST_DELAYS_S = (0.0, 0.002, 0.004)
ROBUST_INPUT_GAINS = (0.8, 1.0, 1.2)
ROBUST_WHEEL_RADII = (0.8, 1.2)
# A payload on link 3 (hostsim.model.params.payload_params), for the designs that are ours (the
# paper's law is the paper's): this mass at the top of link 3, on the physical model with 2 ms of
# delay. The robot carries what an owner puts on it (issue 22: 100 g, half of link 3's mass), and
# the law must hold it without knowing it.
ROBUST_PAYLOAD_KG = 0.15
ROBUST_PAYLOAD_AT_M = 0.1
PAYLOAD_LABEL = "%g kg at the top of link 3" % ROBUST_PAYLOAD_KG
ROBUST_RADIUS_MAX = 0.9995
ROBUST_DAMPING_MIN = 0.05


@dataclasses.dataclass(frozen=True)
class Margins:
    radius: float           # the largest spectral radius over the set
    radius_at: tuple        # (model, delay_s, motor gain, wheel radius factor)
    damping: float          # the least damping ratio above DAMPING_ABOVE_HZ
    damping_at: tuple

    @property
    def robust(self):
        return self.radius <= ROBUST_RADIUS_MAX and self.damping >= ROBUST_DAMPING_MIN


def model_plants(name, p, where, ts_s, delays, gains):
    """[((model, delay_s, motor gain, where), delayed plant, R_w)]: the model variant `name` of
    parameters `p`, linearized in SI, with each delay and motor gain (in that order)."""
    from hostsim.model.equations import RobotModel, state_scale_to_si
    model = RobotModel(name, p)
    ac, bc = model.linearize()
    t = state_scale_to_si(model.variant)
    ac, bc = t @ ac @ np.linalg.inv(t), t @ bc
    return [((name, d, g, where), delayed_plant(ac, bc * g, ts_s, d), p["rw_m"]) for d in delays for g in gains]


class UncertaintySet:
    """The plants of the uncertainty above at one period, built once; margins(kd) -> Margins.
    extra: [(label, parameters)]: more robots, each as the physical model with the duties landing
    2 ms into the tick (hostsim.model.spread: where an identification's fit is loose)."""

    def __init__(self, params, ts_s, extra=(), payload=False):
        from hostsim.model.params import payload_params, scaled_params
        self.plants = []

        def add(name, p, where, delays, gains):
            self.plants += model_plants(name, p, where, ts_s, delays, gains)
        for name in ROBUST_MODELS:
            add(name, params, 1.0, ROBUST_DELAYS_S[::-1], ROBUST_INPUT_GAINS[::-1])   # the harder first
        for f in ROBUST_WHEEL_RADII:
            add("physical", scaled_params({"rw_m": f}, params), f, (0.002,), (1.0,))
        if payload:
            add("physical", payload_params(params, ROBUST_PAYLOAD_KG, ROBUST_PAYLOAD_AT_M), PAYLOAD_LABEL,
                (0.002,), (1.0,))
        for label, p in extra:
            add("physical", p, label, (0.002,), (1.0,))

    @classmethod
    def of(cls, plants):
        """A set of these plants only (model_plants' lists)."""
        out = cls.__new__(cls)
        out.plants = list(plants)
        return out

    def holds(self, kd):
        """margins(kd).robust, stopping at the first plant that fails (for the design's ladder)."""
        for _, plant, rw in self.plants:
            r, z = loop_margins(kd, *plant, rw)
            if r > ROBUST_RADIUS_MAX or z < ROBUST_DAMPING_MIN:
                return False
        return True

    def margins(self, kd):
        radius = damping = None
        for where, plant, rw in self.plants:
            r, z = loop_margins(kd, *plant, rw)
            if radius is None or r > radius[0]:
                radius = (r, where)
            if damping is None or z < damping[0]:
                damping = (z, where)
        return Margins(radius[0], radius[1], damping[0], damping[1])

    @staticmethod
    def describe(payload=False):
        return {"models": list(ROBUST_MODELS), "delays_s": list(ROBUST_DELAYS_S),
                "input_gains": list(ROBUST_INPUT_GAINS), "wheel_radius_factors": list(ROBUST_WHEEL_RADII),
                **({"payload_kg_at_top_of_link_3": ROBUST_PAYLOAD_KG} if payload else {}),
                "radius_max": ROBUST_RADIUS_MAX, "damping_min": ROBUST_DAMPING_MIN,
                "damping_above_hz": DAMPING_ABOVE_HZ}
