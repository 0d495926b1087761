"""Firmware in the loop: the unmodified firmware balancing the simulated robot, in lock-step.

The firmware's session (calibration, loop, safety, log) runs as on the brick, with a
``VirtualClock``: whenever it sleeps, the simulated world catches up to the wake-up time.
The world is the nonlinear plant (hostsim.world.plant), the sensor models (hostsim.world.sensors) and,
with ``sysfs=True``, the fake EV3 tree read and written by the firmware's real device layer
(tipbot_fw.io.ev3dev); with ``sysfs=False`` an in-memory device (faster, for Monte Carlo).

Timing model, per tick of period ts: the firmware reads the sensors at the tick's start,
its duties take effect ``io_latency_s`` later (the rest of the reads and the compute on the
brick), the motor voltage is duty x battery voltage, held until the next write (zero-order
hold), plus the scenario's input disturbance. ``extra_delay_ticks`` delays the voltages by
whole ticks more; ``jitter_s`` makes each wake-up late by |N(0, jitter_s)| (rounded to the
plant's 1 ms step). The plant integrates with the scenario's ``plant_method`` at 1 kHz, one
``advance`` per piece of constant input (hostsim.world.plant).

With a scenario's ``brick`` effects on (hostsim.sim.scenario.Brick), the world is
hostsim.world.lockstep.BrickWorld instead: the same plant on a 1 ms grid with the
drivetrain, the sensors' and the battery's imperfections and, with the brick's timing, every
sysfs access at its own moment (hostsim.world.brick_timing); the brick's timing needs the
fake EV3 tree (``sysfs=True``). With the timing, the firmware's cues in its loop (lights and
tones in the slack after the writes) are given on the fake's lights and speaker, and cost
brick time as on the brick (SlackCues); otherwise the run is quiet.

Start: like a person holding the robot, the world keeps the plant at the scenario's start
pose while the firmware calibrates the gyro (about 1.1 s, with the scenario's gyro bias and
noise), and releases it when the control loop starts; t = 0 in the results is that
release. The firmware is told the start pose (config ``start_pose_rad``). What differs from
the linear simulation, as on the robot:

- the estimate starts from what the firmware is told, not from a given x~(0): the Kalman
  filter (the default) at rest at the start pose with the calibrated bias, the paper's
  detector from its first measurement (x~_0 = y_0);
- the wheel-position origin is where the wheels stand: the firmware counts the relative wheel
  angle phi_rel from its first reading and sets d = R_w (phi_rel + th1) with the tilt it is
  told, so it starts at d = R_w th1(0) whatever the scenario's d(0). It regulates its d to
  0, i.e. the plant's d to ``d_origin_m`` = d(0) - R_w th1(0). Results (x, and the
  firmware's estimates from its log, tipbot_fw.record.replay.signals, shifted by that offset) are in
  the scenario's frame; metrics measure the final displacement from d_origin_m.
"""
import math
import os
import tempfile

import numpy as np

from hostsim.errors import TipbotError
from hostsim.model.equations import RobotModel, state_scale_to_si
from hostsim.model.gains import with_law
from hostsim.model.params import load_params, scaled_params
from hostsim.world.lockstep import BrickWorld, Lockstep
from hostsim.sim.result import RunResult
from hostsim.world.brick_timing import AccessTimes, BrickClock, TimedIO
from hostsim.world.drivetrain import DrivetrainPlant
from hostsim.world.gyro import GyroModel
from hostsim.world.plant import Plant, apply_push, disturbance_at
from hostsim.sim.scenario import firmware_overrides, merged_fields, scenario_load
from hostsim.world.sensors import BatteryModel, EncoderModel, SensorModel
from tipbot_fw import config as fw_config
from tipbot_fw.record import logfile
from tipbot_fw.record import replay as fw_replay
from tipbot_fw.calibration import sample_counts
from tipbot_fw.drive.course import CourseError, parse_course
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cues import QUIET as QUIET_CUES
from tipbot_fw.cues import OwnerCues
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.drive.plan import drive_problem
from tipbot_fw.io.lights_speaker import BrickSignals
from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.gains import gains_from_dict, load_gains
from tipbot_fw.vocabulary import ACTUATED_INPUTS
from tipbot_fw.guard.safety import DevicesMissing
from tipbot_fw.session import log_refused_start, open_log, run_session

DEFAULT_IO_LATENCY_S = 0.002
PLANT_DT_S = 0.001
_EPS_S = 1e-9


# Coulomb friction is given as the duty that just starts a free motor at this battery voltage
# (../shared/ev3-hardware.md: about 4 % on a Large motor, 10 % on a Medium one, at 8 V).
DEADBAND_REFERENCE_V = 8.0
# The fake EV3's random draws (brick timing, gyro effects) use their own generators, seeded
# (scenario seed, stream), so that switching one effect leaves the others' draws alone.
STREAM_TIMING, STREAM_GYRO = 1, 2


class SimulationError(TipbotError):
    """A scenario the firmware-in-the-loop simulation cannot run as asked."""


class SlackCues(OwnerCues):
    """The owner's cues the firmware gives inside its loop (the rest of the let-go melody,
    'balancing', a battery warning: tipbot_fw.cues.LoopCues, a side task in the slack after
    the writes), on the fake EV3's lights and speaker through the brick's timed I/O, so that
    they cost brick time as on the brick. The blocking light-and-melody shows before the
    calibration and after the stop are left out: they are outside the loop, and the run's
    record ends where the firmware's does."""

    def __init__(self, signals):
        OwnerCues.__init__(self, streams=(), brick=signals)

    def _signal(self, state):
        pass


def firmware_config(sc, rw_m, overrides=None):
    """The firmware's configuration for a scenario: defaults + what the scenario implies +
    the scenario's firmware_config (hostsim.sim.scenario.firmware_overrides) + overrides."""
    doc = merged_fields(firmware_overrides(sc.x0_si, sc.sensors.gyro_sign, sc.firmware_config, rw_m), overrides or {})
    return fw_config.config_from_overrides(doc, "scenario %s, firmware_config" % sc.name)


def calibration_end_s(config, ts_s):
    """When the session's gyro calibration takes its last sample (see tipbot_fw.calibration)."""
    settle, n = sample_counts(config["gyro_calibration"], ts_s)
    return (settle + n - 1) * ts_s


class World(Lockstep):
    """Plant + sensors (+ fake EV3), advanced by the firmware's clock."""

    def __init__(self, sc, plant, sensors, ts_s, t_release_s, fake=None, io_latency_s=DEFAULT_IO_LATENCY_S,
                 rng=None):
        self.sc = sc
        self.plant = plant
        self.sensors = sensors
        self.ts_s = ts_s
        self.t_release_s = t_release_s
        self.fake = fake
        self.io_latency_s = io_latency_s
        self.rng = rng
        self.devices = None                     # MemoryDevices, when not on the fake
        self.ports = None                       # fake EV3 motor ports, in MOTOR_ROLES order
        self.battery_v = sc.sensors.battery_v
        self.pushes = sorted(((t_release_s + p.t_s, p) for p in sc.pushes), key=lambda tp: tp[0])
        edges = {t for d in sc.disturbances for t in (d.t_start_s, d.t_end_s)}
        self.breaks = sorted({t_release_s + t for t in edges} | {t for t, _ in self.pushes})
        self.delay = [np.zeros(5)] * sc.extra_delay_ticks
        self.v_prev = np.zeros(5)
        self.readings = None
        self.log_t, self.log_x, self.log_u, self.log_w = [], [], [], []
        self.released = False
        self.io_marks = []
        self.clock = None
        self.publish(0.0)

    # -- what the firmware sees
    def publish(self, t_s):
        x = self.plant.x_si
        enc, gyro, volts = self.sensors.read(x, t_s)
        self.readings = (enc, gyro)
        if self.fake is not None:
            self.fake.poll(t_s)   # client writes (mode, commands) take effect before the next read
            self.fake.set_readings(enc, gyro, volts)

    def read(self):
        """MemoryDevices source: the readings published at the current time."""
        return self.readings

    def battery_reading(self):
        return self.battery_v

    # -- what the firmware commands
    def duties(self):
        if self.fake is not None:
            states = self.fake.poll()
            return [states[p].duty if states[p].running else 0 for p in self.ports]
        return self.devices.duties

    def motor_volts(self):
        v = np.zeros(5)
        signs = self.sensors.motor_signs
        scale = self.battery_v / 100.0
        for i, d in enumerate(self.duties()):
            v[ACTUATED_INPUTS[i]] = signs[i] * d * scale
        return v

    # -- time
    def on_sleep(self, t_from, t_to):
        if t_to <= self.t_release_s + _EPS_S:          # held still while calibrating
            self.publish(t_to)
            return
        t_from, t_to = self._wake(t_from, t_to, PLANT_DT_S)
        self.delay.append(self.motor_volts())
        v_new = self.delay.pop(0)
        t_switch = min(t_from + self.io_latency_s, t_to)
        self._integrate(t_from, t_switch, self.v_prev)
        self._integrate(t_switch, t_to, v_new)
        self.v_prev = v_new
        self.log_u.append(v_new)
        self.log_w.append(self._w(t_switch, t_to))
        self._record(t_to)
        self.publish(t_to)

    def _w(self, t0, t1):
        # The disturbance over a piece without edges: sampled mid-piece, so rounding of the
        # absolute times cannot pick the neighbouring value.
        return np.array(disturbance_at(self.sc, 0.5 * (t0 + t1) - self.t_release_s))

    def _integrate(self, t0, t1, volts):
        while t1 - t0 > 1e-12:
            while self.pushes and self.pushes[0][0] <= t0 + _EPS_S:
                apply_push(self.plant, self.pushes.pop(0)[1])
            t_end = t1
            for b in self.breaks:
                if t0 + _EPS_S < b < t_end - _EPS_S:
                    t_end = b
                    break
            self.plant.advance(volts + self._w(t0, t_end), t_end - t0)
            t0 = t_end


def pd_gains_document(doc, k_pd_file):
    """A gains document whose law is the PD baseline: K = K_pd (file units), K_w = 0.

    The firmware's law is u = -K x^ - K_w w^; with this document it applies the PD to its
    estimate x^ (the Kalman filter's by default, the detector's with estimator=detector).
    """
    return with_law(doc, k_pd_file, np.zeros((5, 5)), " + hostsim.pd baseline")


def run_firmware(sc, gains_path=None, gains_doc=None, sysfs=True, log_path=None, keep_rows=True, params=None,
                 config_overrides=None):
    """Run a scenario with the firmware in the loop.

    gains_doc (a parsed gains document) replaces the file at gains_path / sc.gains.
    keep_rows: read the firmware's log back for its estimates (a temporary log unless
    log_path is given); without it only the plant's side is returned.

    -> RunResult: t_s (tick times from the release), x (plant state at the ticks, SI), u (the
    motors' volts over each tick, from the duties), w (the disturbance added to them),
    d_origin_m (see the module docstring), exit_code, stop_reason, completed, header (the
    firmware log's), io_per_iteration (sysfs runs only: the device layer's (op, path, bytes)
    between two consecutive sleeps of the loop), and with keep_rows: xhat, w_hat, y (the
    firmware's, shifted into the scenario's frame), u_cmd (the inputs the firmware applied),
    u_unsat (before saturation).
    """
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
    course = _course(sc, gains, config)
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
        from tipbot_fw.io.ev3dev import Ev3Devices
        fake = FakeEV3(battery_v=s.battery_v, gyro_mode_write_s=brick.gyro_mode_write_s,
                       gyro_mode_timeout=brick.gyro_mode_timeout)
    if brick.ideal:
        world = World(sc, plant, sensors, gains.ts_s, t_release, fake=fake, io_latency_s=sc.io_latency_s, rng=rng)
        clock = VirtualClock(on_sleep=world.on_sleep)
        io = None if fake is None else fake.io
    else:
        world = _brick_world(sc, plant, sensors, signs, p, config, gains.ts_s, t_release, fake, ports, rng)
        clock = BrickClock(on_sleep=world.on_sleep)
        io = None if fake is None else TimedIO(fake.io, fake, clock, world, world.times,
                                               end_of_reads=fake.relpath(config["ports"]["gyro"], "bin_data"))
    world.clock = clock
    tmp = None
    if keep_rows and log_path is None:
        tmp = tempfile.TemporaryDirectory(prefix="tipbot-fil-")
        log_path = os.path.join(tmp.name, "run.log")
    rows = None
    try:
        # as tipbot_fw.cli: the log is opened before the devices, so a refused start has one too
        log = open_log(log_path, gains, config, sc.duration_s) if log_path else None
        if sysfs:
            world.ports = ports
            try:
                devices = Ev3Devices(config, sysfs_root=fake.sysfs_root, io=io)
            except Exception as e:      # as tipbot_fw.cli: a header-only log that says why, exit 3
                devices = None
                error = DevicesMissing(" ".join(("%s: %s" % (type(e).__name__, e)).split()))
                if log is not None:
                    log_refused_start(log, gains, config, sc.duration_s, error, say=lambda msg: None)
                code, header = error.exit_code, {"stop_reason": error.reason, "stop_message": str(error)}
        else:
            devices = MemoryDevices(source=world.read, battery_v=world.battery_reading)
            world.devices = devices
        if devices is not None:
            cues = QUIET_CUES
            if brick.timed:       # the loop's lights and tones cost brick time (brick_timing)
                cues = SlackCues(BrickSignals(fake.sysfs_root, io=io, now=clock.now,
                                              sleep=lambda s: clock.sleep_until(clock.now() + s)))
            if isinstance(world, BrickWorld):
                world.start_at(clock.t)   # a blocking set-up (the gyro's mode write) took this long
            try:
                code, header = run_session(devices, gains, config, clock, log=log,
                                           duration_s=sc.duration_s, say=lambda msg: None, cues=cues,
                                           course=course)
            finally:
                cues.close()
                devices.close()
            if header.get("stop_reason") == "keyboard_interrupt":
                # the owner's Ctrl-C, which the firmware's own guard turned into a planned stop:
                # the simulated world sends no signals, so it ends the host's job too (make sim)
                raise KeyboardInterrupt
            if keep_rows and os.path.exists(log_path):
                log_header, rows = logfile.read_log(log_path)
    finally:
        if fake is not None:
            fake.close()
        if tmp is not None:
            tmp.cleanup()
    if not world.released:                      # stopped at its first tick
        world._record(world.t_release_s)
    rw = config["wheel_radius_m"]
    x0 = sc.x0_si
    # The firmware counts its wheel position from R_w times the tilt it is told (module docstring).
    th1_told = config["start_pose_rad"]["th1"]
    d_origin = np.array([x0[0] - rw * th1_told, x0[1] - rw * th1_told])
    out = _world_side(world)
    if fake is not None:
        out["io_per_iteration"] = [fake.io.log[a:b] for a, b in zip(world.io_marks, world.io_marks[1:])]
    if rows is not None:
        out.update(_firmware_side(log_header, rows, gains, d_origin, len(out["t_s"])))
    if isinstance(world, BrickWorld):
        out["duty_events"] = world.duty_events
    return RunResult(d_origin_m=d_origin, exit_code=code, stop_reason=header.get("stop_reason"), header=header,
                     completed=code == 0 and header.get("stop_reason") == "completed", **out)


def _course(sc, gains, config):
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


def _brick_world(sc, plant, sensors, signs, p, config, ts_s, t_release, fake, ports, rng):
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
    settle, n = sample_counts(config["gyro_calibration"], ts_s)
    return BrickWorld(sc, plant, sensors, encoders, gyro, battery, signs, ts_s, t_release, settle + n,
                      fake=fake, ports=ports, rng=rng, times=times)


def _world_side(world):
    """What the plant did: t_s, x, u, w."""
    n = len(world.log_t)
    u = np.zeros((n, 5))
    w = np.zeros((n, 5))
    m = len(world.log_u)
    if m:
        # log_u[k] is what the plant got over tick k; the last tick has none: repeat.
        u[:m], w[:m] = world.log_u[:n], world.log_w[:n]
        u[m:], w[m:] = world.log_u[-1], world.log_w[-1]
    return dict(t_s=np.array(world.log_t), x=np.array(world.log_x).reshape(n, 10), u=u, w=w)


def _firmware_side(header, rows, gains, d_origin, n):
    """The firmware's own view from its log (tipbot_fw.record.replay.signals), tick k <-> plant sample k
    (NaN for the ticks a long run's bounded log did not keep, and after its last row)."""
    ticks = logfile.tick_indices(header, len(rows))
    dense = np.full((min(n, int(ticks[-1]) + 1 if len(ticks) else 0), rows.shape[1]), np.nan)
    dense[ticks[ticks < len(dense)]] = rows[ticks < len(dense)]
    rows = dense
    sig = fw_replay.signals(header, rows[:n], gains)
    shift = np.zeros(10)
    shift[:2] = d_origin
    xhat = sig["x_hat"] + shift
    w_hat, u_cmd, u_unsat = sig["w_hat"], sig["u"], sig["u_cmd"]
    names = [c["name"] for c in header["columns"]]
    flags, tick = (rows[:n, names.index(c)][:, None] for c in ("flags", "tick_s"))
    if len(xhat) < n:
        pad = n - len(xhat)
        xhat, w_hat, u_cmd, u_unsat, flags, tick = (np.vstack([a, np.full((pad, a.shape[1]), np.nan)])
                                                    for a in (xhat, w_hat, u_cmd, u_unsat, flags, tick))
    return dict(xhat=xhat, w_hat=w_hat, u_cmd=u_cmd, u_unsat=u_unsat, flags=flags[:, 0], tick_work_s=tick[:, 0])
