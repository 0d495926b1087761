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
import os
import tempfile

from hostsim.sim.firmware_build import build_run
from hostsim.sim.firmware_readback import read_back
from hostsim.world.lockstep import BrickWorld
from tipbot_fw.cues import QUIET as QUIET_CUES
from tipbot_fw.cues import OwnerCues
from tipbot_fw.guard.safety import DevicesMissing
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.io.lights_speaker import BrickSignals
from tipbot_fw.record import logfile
from tipbot_fw.session import log_refused_start, open_log, run_session


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


def run_firmware(sc, gains_path=None, gains_doc=None, sysfs=True, log_path=None, keep_rows=True, params=None,
                 config_overrides=None):
    """Run a scenario with the firmware in the loop: build it (hostsim.sim.firmware_build), run
    the firmware's session on its world, read it back (hostsim.sim.firmware_readback).

    gains_doc (a parsed gains document) replaces the file at gains_path / sc.gains.
    keep_rows: read the firmware's log back for its estimates (a temporary log unless
    log_path is given); without it only the plant's side is returned.

    -> RunResult: t_s (tick times from the release), x (plant state at the ticks, SI), u (the
    motors' volts over each tick, from the duties), w (the disturbance added to them),
    d_origin_m (see the module docstring), exit_code, stop_reason, completed, header (the
    firmware log's), io_per_iteration (sysfs runs only: the device layer's (op, path, bytes)
    between two consecutive sleeps of the loop), and with keep_rows: xhat, w_hat, y (the
    firmware's, shifted into the scenario's frame), u_applied (the inputs the firmware applied),
    u_unsat (its law's output before saturation).
    """
    run = build_run(sc, gains_path, gains_doc, sysfs, params, config_overrides)
    tmp = None
    if keep_rows and log_path is None:
        tmp = tempfile.TemporaryDirectory(prefix="tipbot-firmware-run-")
        log_path = os.path.join(tmp.name, "run.log")
    log_header = rows = None
    try:
        code, header, started = _session(run, log_path, sc.duration_s)
        if started and keep_rows and os.path.exists(log_path):
            log_header, rows = logfile.read_log(log_path)
    finally:
        if run.fake is not None:
            run.fake.close()
        if tmp is not None:
            tmp.cleanup()
    return read_back(run, code, header, log_header, rows)


def _session(run, log_path, duration_s):
    """The firmware's session on the run's world, as tipbot_fw.cli runs it -> (exit code, header,
    whether the devices were set up and the session ran)."""
    gains, config, world, clock, fake, io = run.gains, run.config, run.world, run.clock, run.fake, run.io
    # as tipbot_fw.cli: the log is opened before the devices, so a refused start has one too
    log = open_log(log_path, gains, config, duration_s) if log_path else None
    if fake is not None:
        world.ports = run.ports
        try:
            from tipbot_fw.io.ev3dev import Ev3Devices
            devices = Ev3Devices(config, sysfs_root=fake.sysfs_root, io=io)
        except Exception as e:      # as tipbot_fw.cli: a header-only log that says why, exit 3
            error = DevicesMissing(" ".join(("%s: %s" % (type(e).__name__, e)).split()))
            if log is not None:
                log_refused_start(log, gains, config, duration_s, error, say=lambda msg: None)
            return error.exit_code, {"stop_reason": error.reason, "stop_message": str(error)}, False
    else:
        devices = MemoryDevices(source=world.read, battery_v=world.battery_reading)
        world.devices = devices
    cues = QUIET_CUES
    if run.sc.brick.timed:       # the loop's lights and tones cost brick time (brick_timing)
        cues = SlackCues(BrickSignals(fake.sysfs_root, io=io, now=clock.now,
                                      sleep=lambda s: clock.sleep_until(clock.now() + s)))
    if isinstance(world, BrickWorld):
        world.start_at(clock.t)   # a blocking set-up (the gyro's mode write) took this long
    try:
        code, header = run_session(devices, gains, config, clock, log=log, duration_s=duration_s,
                                   say=lambda msg: None, cues=cues, course=run.course)
    finally:
        cues.close()
        devices.close()
    if header.get("stop_reason") == "keyboard_interrupt":
        # the owner's Ctrl-C, which the firmware's own guard turned into a planned stop:
        # the simulated world sends no signals, so it ends the host's job too (make sim)
        raise KeyboardInterrupt
    return code, header, True
