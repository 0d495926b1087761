"""The owner's experiments (tipbot_fw.experiments) on a simulated robot, in lock-step.

The firmware's own experiment code (calibration, loop, joint PD, log) runs with a
``VirtualClock`` whose sleeps advance the world: the physical plant with the drivetrain
(hostsim.world.drivetrain: rotors, Coulomb friction, backlash), encoders that latch every 2 ms
and truncate, the gyro's latency, scale error, drift and steps (hostsim.world.gyro), all at the
values of a brick scenario (default scenarios/brick_realistic.json). The duties of a tick land
``IO_LATENCY_S`` into it; readings are those of the last 1 ms step before the read.

- the fall: a hand holds the robot at ``hold_tilt_rad`` (the firmware is told it stands at its
  start pose, 0: an owner's upright is a degree or two off) during the calibration, and lets go
  ``REACTION_S`` after the LET GO cue; a cushion stops it past ``CUSHION_RAD``;
- the swing: link 1 on a stand (hostsim.world.stand) throughout, upright, or upside down (th1 = pi)
  for a joint the firmware swings hanging (tipbot_fw.experiments.HANGING); the axle swing (joint 1): the
  robot upside down (th1 = pi), hanging from its wheels held (the stand holds d_r and d_l only),
  the wheel motors with their friction and gear play.

``simulate_experiment`` -> (exit code, log header); the log at ``log_path`` is the brick's.
"""
import math

import numpy as np

from hostsim.model.equations import RobotModel
from hostsim.sim.firmware_build import firmware_config, friction_torques_nm
from hostsim.sim.scenario import load_scenario
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.gyro import GyroModel
from hostsim.world.sensors import BatteryModel, EncoderModel
from hostsim.world.stand import Stand
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.config import MOTOR_ROLES
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.experiments import HANGING, run_experiment

DT_S = 0.001
IO_LATENCY_S = 0.002
REACTION_S = 0.25
CUSHION_RAD = 0.9
BRICK_SCENARIO = "brick_realistic"


class ExperimentWorld:
    """Plant, encoders, gyro and battery on a 1 ms grid, advanced by the firmware's sleeps."""

    def __init__(self, plant, encoders, gyro, battery, signs, hold=True):
        self.plant = plant
        self.encoders = encoders
        self.gyro = gyro
        self.battery = battery
        self.signs = signs
        self.k = 0
        self.frac = [0.0] * 4
        self.held = hold                 # a hand holds the robot still (the fall, before the release)
        self.cushion = hold              # the fall ends on a cushion
        self.release_s = None
        self.landed = False
        self.devices = None
        self.battery_v = battery.v_oc
        self.max_abs_th1 = 0.0

    def read(self):
        t = self.k * DT_S
        return self.encoders.read(self.plant.motor_angles()), self.gyro.read(t)

    def battery_reading(self):
        return self.battery.reading(self.battery_v)

    def _step(self, frac):
        t0 = self.k * DT_S
        if self.release_s is not None and t0 + 1e-9 >= self.release_s:
            self.held = False
        if not self.held and not self.landed:
            v = self.battery_v = self.battery.voltage(frac, self.plant.motor_speeds())
            u = [frac[0] * v, frac[1] * v, 0.0, frac[2] * v, frac[3] * v]
            self.plant.advance(u, DT_S)
            th1 = float(self.plant.x_si[2])
            self.max_abs_th1 = max(self.max_abs_th1, abs(th1))
            if self.cushion and abs(th1) > CUSHION_RAD:
                self.landed = True
                self.plant.x[5:] = 0.0
        self.k += 1
        if self.encoders.every and self.k % self.encoders.every == 0:
            self.encoders.on_step(self.k, self.plant.motor_angles())
        self.gyro.on_step(self.k * DT_S, 0.0 if (self.held or self.landed) else float(self.plant.x[7]))

    def on_sleep(self, t_from, t_to):
        new = [s * d / 100.0 for s, d in zip(self.signs, self.devices.duties)]
        t_switch = t_from + IO_LATENCY_S
        while (self.k + 1) * DT_S <= t_to + 1e-9:
            self._step(self.frac if (self.k + 1) * DT_S <= t_switch + 1e-9 else new)
        self.frac = new


def simulate_experiment(kind, params, log_path, joint=None, seed=0, hold_tilt_rad=0.02, scenario=BRICK_SCENARIO):
    """Run the firmware's ``kind`` experiment ('fall', or 'swing' of ``joint``) on the robot of
    ``params`` (the true parameters). -> (exit code, log header, world)."""
    sc = load_scenario(scenario)
    b = sc.brick
    model = RobotModel("physical", params)
    x0 = np.zeros(10)
    if kind == "fall":
        x0[2] = hold_tilt_rad
    axle = kind == "swing" and joint == 1
    if axle or (kind == "swing" and HANGING[joint]):
        x0[2] = math.pi
    friction = friction_torques_nm(b.friction_deadband_pct, params)
    backlash = [math.radians(d) for d in b.backlash_deg]
    if kind == "swing" and not axle:
        # the wheels turn freely in the air and take no part in the swing: their motors' friction
        # and free play are left out (a stuck wheel's constraint against the stiff stand is not
        # something the drivetrain's per-step events integrate well)
        friction[:2], backlash[:2] = [0.0, 0.0], [0.0, 0.0]
    plant = DrivetrainPlant(model, x0, dt_s=DT_S, method="heun", friction_nm=friction, backlash_rad=backlash)
    if kind == "swing":
        plant.load = Stand(model, x0, held=(0, 1) if axle else (0, 1, 2), dt_s=DT_S)
    config = firmware_config(sc, params["rw_m"])
    signs = tuple(config["polarity"][r] for r in MOTOR_ROLES)
    rng = np.random.default_rng([seed, 7])
    s = sc.sensors
    gyro = GyroModel(DT_S, gyro_sign=int(s.gyro_sign), bias_dps=s.gyro_bias_dps, noise_dps=s.gyro_noise_dps,
                     rng=rng, fx_rng=np.random.default_rng([seed, 8]), latency_s=b.gyro_latency_s,
                     scale_error=b.gyro_scale_error, bias_walk_dps_rt_s=b.gyro_bias_walk_dps_rt_s,
                     bias_ramp_dps_s=b.gyro_bias_ramp_dps_s, rate_step_dps=b.gyro_rate_step_dps)
    encoders = EncoderModel(signs, (360,) * 4, DT_S, b.encoder_update_s, b.encoder_truncate)
    battery = BatteryModel(s.battery_v, b.battery_r_ohm, b.battery_quantum_v,
                           [params[r + "_ke_v_s"] for r in MOTOR_ROLES], [params[r + "_ra_ohm"] for r in MOTOR_ROLES])
    world = ExperimentWorld(plant, encoders, gyro, battery, [signs[i] for i in range(4)], hold=kind == "fall")
    devices = MemoryDevices(source=world.read, battery_v=world.battery_reading)
    world.devices = devices
    clock = VirtualClock(on_sleep=world.on_sleep)

    def cue(text):
        if text.startswith("LET GO"):
            world.release_s = clock.now() + REACTION_S
    if kind == "swing":
        world.held = False
    code, header = run_experiment(kind, devices, clock, config, joint=joint, log_path=log_path,
                                  say=lambda m: None, cue=cue)
    return code, header, world

