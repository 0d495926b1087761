"""Building a firmware-in-the-loop run (hostsim.sim.firmware_run): the gains, the firmware's
configuration and course for a scenario, and the world it meets (hostsim.world.lockstep: the
plant, the sensors, with ``sysfs`` the fake EV3 tree, the firmware's clock).
"""
import dataclasses
import math
from typing import Any, Optional

import numpy as np

from hostsim.errors import TipbotError
from hostsim.model.equations import RobotModel, state_scale_to_si
from hostsim.model.gains import with_law
from hostsim.model.params import load_params, scaled_params
from hostsim.sim.scenario import firmware_overrides, merged_fields, scenario_load
from hostsim.world.brick_timing import AccessTimes, BrickClock, TimedIO
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.gyro import GyroModel
from hostsim.world.lockstep import PLANT_DT_S, BrickWorld, World
from hostsim.world.plant import Plant
from hostsim.world.sensors import BatteryModel, EncoderModel, SensorModel
from tipbot_fw import config as fw_config
from tipbot_fw import calibration
from tipbot_fw.drive.course import CourseError, parse_course
from tipbot_fw.drive.plan import drive_problem
from tipbot_fw.gains import gains_from_dict, load_gains
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.vocabulary import MOTOR_ROLES

# Coulomb friction is given as the duty that just starts a free motor at this battery voltage
# (../shared/ev3-hardware.md: about 4 % on a Large motor, 10 % on a Medium one, at 8 V).
DEADBAND_REFERENCE_V = 8.0
# The fake EV3's random draws (brick timing, gyro effects) use their own generators, seeded
# (scenario seed, stream), so that switching one effect leaves the others' draws alone.
STREAM_TIMING, STREAM_GYRO = 1, 2


class SimulationError(TipbotError):
    """A scenario the firmware-in-the-loop simulation cannot run as asked."""


@dataclasses.dataclass(frozen=True)
class FirmwareRun:
    """What a run is made of: the scenario, the firmware's gains, configuration and course, and
    the world with its clock, its fake EV3 (None: in-memory devices), the fake's I/O as the
    firmware's device layer sees it (timed on an unkind brick) and the motors' ports."""
    sc: Any
    gains: Any
    config: dict
    course: Optional[list]
    world: Any
    clock: Any
    fake: Any = None
    io: Any = None
    ports: tuple = ()


def firmware_config(sc, rw_m, overrides=None):
    """The firmware's configuration for a scenario: defaults + what the scenario implies +
    the scenario's firmware_config (hostsim.sim.scenario.firmware_overrides) + overrides."""
    doc = merged_fields(firmware_overrides(sc.x0_si, sc.sensors.gyro_sign, sc.firmware_config, rw_m), overrides or {})
    return fw_config.config_from_overrides(doc, "scenario %s, firmware_config" % sc.name)


def calibration_end_s(config, ts_s):
    """When the session's gyro calibration takes its last sample, the clock starting at 0: what
    the simulated hand holds the robot for (the firmware's schedule, tipbot_fw.calibration; the
    run's log records when it did: read_back checks the two agree)."""
    return calibration.window_s(config["gyro_calibration"], ts_s)


def pd_gains_document(doc, k_pd_file):
    """A gains document whose law is the PD baseline: K = K_pd (file units), K_w = 0.

    The firmware's law is u = -K x^ - K_w w^; with this document it applies the PD to its
    estimate x^ (the Kalman filter's by default, the detector's with estimator=detector).
    """
    return with_law(doc, k_pd_file, np.zeros((5, 5)), " + hostsim.pd baseline")


def build_run(sc, gains_path=None, gains_doc=None, sysfs=True, params=None, config_overrides=None):
    """The run of a scenario, ready to start (run_firmware's arguments) -> FirmwareRun."""
    gains_path = gains_path or sc.gains
    brick = sc.brick
    if brick.needs_sysfs and not sysfs:
        raise SimulationError("scenario %s: the brick's timing (brick.*_access_s, compute_s, late wakes, stalls) "
                              "and the gyro's mode write act through the fake EV3 tree: run it with the sysfs "
                              "device" % sc.name)
    rng = np.random.default_rng(sc.seed)
    nominal = load_params() if params is None else params
    p = scaled_params(sc.param_scale, nominal)
    model = RobotModel(sc.plant_variant, p)
    to_model = 1.0 / np.diag(state_scale_to_si(model.variant))
    x0_model = np.array(sc.x0_si) * to_model
    if brick.drivetrain:
        plant = DrivetrainPlant(model, x0_model, dt_s=PLANT_DT_S, method=sc.plant_method,
                                friction_nm=friction_torques_nm(brick.friction_deadband_pct, p),
                                backlash_rad=[math.radians(d) for d in brick.backlash_deg])
    else:
        plant = Plant(model, x0_model, dt_s=PLANT_DT_S, method=sc.plant_method)
    plant.load = scenario_load(sc, model, x0_model)
    if gains_doc is not None:
        gains = gains_from_dict(gains_doc, "<%s gains for %s>" % (gains_doc["model_variant"], sc.name))
    else:
        gains = load_gains(gains_path)
    config = firmware_config(sc, nominal["rw_m"], config_overrides)
    course = scenario_course(sc, gains, config)
    s = sc.sensors
    signs = tuple(config["polarity"][r] for r in MOTOR_ROLES)
    sensors = SensorModel(p["rw_m"], motor_signs=signs, gyro_sign=int(s.gyro_sign),
                          gyro_bias_dps=s.gyro_bias_dps, gyro_noise_dps=s.gyro_noise_dps, rng=rng,
                          battery_v=s.battery_v)
    t_release = calibration_end_s(config, gains.ts_s)
    ports = tuple(config["ports"][r] for r in MOTOR_ROLES)
    fake = None
    if sysfs:
        from hostsim.world.fake_ev3 import FakeEV3
        fake = FakeEV3(battery_v=s.battery_v, gyro_mode_write_s=brick.gyro_mode_write_s,
                       gyro_mode_timeout=brick.gyro_mode_timeout)
    if brick.ideal:
        world = World(sc, plant, sensors, gains.ts_s, t_release, fake=fake, io_latency_s=sc.io_latency_s, rng=rng)
        clock = VirtualClock(on_sleep=world.on_sleep)
        io = None if fake is None else fake.io
    else:
        world = brick_world(sc, plant, sensors, signs, p, config, gains.ts_s, t_release, fake, ports, rng)
        clock = BrickClock(on_sleep=world.on_sleep)
        io = None if fake is None else TimedIO(fake.io, fake, clock, world, world.times,
                                               end_of_reads=fake.relpath(config["ports"]["gyro"], "bin_data"))
    world.clock = clock
    return FirmwareRun(sc=sc, gains=gains, config=config, course=course, world=world, clock=clock, fake=fake, io=io,
                       ports=ports)


def scenario_course(sc, gains, config):
    """The scenario's course, checked against the gains' limits as the firmware's --course is."""
    if sc.course is None:
        return None
    problem = drive_problem(gains, config)
    doc = [{"speed_mps": v, "yaw_rate_dps": math.degrees(w), "duration_s": d} for v, w, d in sc.course]
    try:
        if problem:
            raise CourseError("cannot drive: " + problem)
        return parse_course(doc, "scenario %s" % sc.name, gains.kalman.reference.limits, "course")
    except CourseError as e:
        raise SimulationError(str(e))


def friction_torques_nm(deadband_pct, params):
    """Coulomb friction torque (N m, output side) per motor from its dead band: the duty (%)
    at DEADBAND_REFERENCE_V that just overcomes it, through the motor's Km / Ra."""
    return [pct / 100.0 * DEADBAND_REFERENCE_V * params[r + "_km_nm_a"] / params[r + "_ra_ohm"]
            for pct, r in zip(deadband_pct, MOTOR_ROLES)]


def brick_world(sc, plant, sensors, signs, p, config, ts_s, t_release, fake, ports, rng):
    """A BrickWorld for the scenario's brick effects."""
    b = sc.brick
    s = sc.sensors
    gyro = None
    if b.gyro_effects:
        gyro = GyroModel(PLANT_DT_S, gyro_sign=int(s.gyro_sign), bias_dps=s.gyro_bias_dps,
                         noise_dps=s.gyro_noise_dps, rng=rng, fx_rng=np.random.default_rng([sc.seed, STREAM_GYRO]),
                         latency_s=b.gyro_latency_s, freeze_s=b.gyro_freeze_s,
                         freeze_interval_s=b.gyro_freeze_interval_s, scale_error=b.gyro_scale_error,
                         bias_walk_dps_rt_s=b.gyro_bias_walk_dps_rt_s, bias_ramp_dps_s=b.gyro_bias_ramp_dps_s,
                         rate_step_dps=b.gyro_rate_step_dps)
    encoders = EncoderModel(signs, sensors.counts_per_rot, PLANT_DT_S, b.encoder_update_s, b.encoder_truncate)
    battery = BatteryModel(s.battery_v, b.battery_r_ohm, b.battery_quantum_v,
                           [p[r + "_ke_v_s"] for r in MOTOR_ROLES], [p[r + "_ra_ohm"] for r in MOTOR_ROLES])
    times = AccessTimes(b, np.random.default_rng([sc.seed, STREAM_TIMING])) if b.timed else None
    settle, n = calibration.sample_counts(config["gyro_calibration"], ts_s)
    return BrickWorld(sc, plant, sensors, encoders, gyro, battery, signs, ts_s, t_release, settle + n,
                      fake=fake, ports=ports, rng=rng, times=times)
