"""A real-time fake EV3: the simulated robot behind a fake sysfs tree, on the wall clock.

    python -m hostsim fake-robot --root DIR [--scenario FILE|NAME] [--duration S]
                                 [--write-config FILE] [--trace FILE.npz]

creates a hostsim.world.fake_ev3 tree in DIR and keeps it in step with the nonlinear plant
(hostsim.world.plant, the scenario's plant variant and parameter scales) and the sensor models
(hostsim.world.sensors) in real time, so that the unmodified firmware can run against it as a
SEPARATE process, exactly as on the brick:

    python3 -m tipbot_fw run --gains gains/physical.json --config CFG --sysfs-root DIR

(or the deployed launcher over ssh: tests/test_deploy.py). The files on disk are the only
link between the two processes. This is the real-time counterpart of hostsim.sim.firmware_run, which runs
the firmware in lock-step with a virtual clock in one process.

Every ~1 ms (--step-ms) the loop reads what the firmware wrote (FakeEV3.poll), integrates
the plant from the previous poll to now with the voltages seen at the previous poll held
(zero-order hold: the duty a client writes acts from the poll that sees it, 0-1 ms later),
and publishes the new encoder counts, gyro angle/rate and battery voltage.

Start: like a person holding the robot, the plant stays at the scenario's start pose (x0_si)
until the firmware drives a motor (a nonzero duty in run-direct) or until --hold-s seconds
after the firmware's start-up (its motors set to run-direct; the gyro calibration at start
must have ended by then). The scenario's pushes and disturbances are timed from that
release. If |th1| passes 90 degrees the robot lies on the floor: the plant is frozen there.
Each firmware run (from its motors' start-up to their stop) gets the robot held at the start
pose again, as an owner picks the robot up before restarting it: no run starts lying on the
floor, where a still gyro and still wheels would look like a robot in balance.

--stand holds link 1 upright; --hang holds the robot upside down by its wheels, th1 = pi, link 1
free to swing about the axle (the axle swing, swing-test --joint 1), and the robot has "fallen" 90
degrees from hanging; both hold link 1 upside down, the links hanging below it (the joint swings,
swing-test --joint 2 and 3).

The gyro: from the fake's start it counts the angle of its first mode, with the scenario's
bias, until the firmware switches it to GYRO-G&A; the first samples after the switch are
still the old mode's (hostsim.world.fake_ev3.GYRO_MODE_SWITCH_S), as on the real sensor.

The firmware must be told the start pose, gyro mounting and wheel radius: --write-config
FILE writes the matching firmware configuration (hostsim.sim.firmware_build.firmware_config; realtime
priority 0), for `--config` or for `make deploy CONFIG=FILE`.

Prints "fake_robot: ready ..." once the tree exists, what the brick shows (its status lights
when they change, the notes of each melody), a summary when it stops (after --duration
seconds, or on SIGTERM / SIGINT). Not for accuracy studies: the host's scheduling
makes runs unrepeatable; use hostsim.sim.firmware_run for that.
"""
import argparse
import json
import math
import signal
import sys
import time

import hostsim
import numpy as np

from hostsim.errors import TipbotError
from hostsim.world.fake_ev3 import DEFAULT_MOTOR_PORTS, FakeEV3, FakeEV3Error
from hostsim.sim.firmware_build import firmware_config
from hostsim.model.equations import RobotModel, state_scale_to_si
from hostsim.model.params import load_params, scaled_params
from hostsim.world.plant import Plant, disturbance_at
from hostsim.world.stand import Stand
from hostsim.sim.scenario import load_scenario, parse_scenario
from hostsim.world.sensors import SensorModel
from tipbot_fw.config import ConfigError
from tipbot_fw.vocabulary import ACTUATED_INPUTS, MOTOR_ROLES

DEFAULT_STEP_S = 0.001
# The firmware's start-up to the end of its gyro calibration is about 1.1 s
# (tipbot_fw.calibration); the rest is margin for a busy host.
DEFAULT_HOLD_S = 2.0
PLANT_DT_S = 0.001
FALLEN_RAD = math.pi / 2
# How often the lights and the speaker are looked at, and the pause that ends a melody.
SIGNALS_EVERY_S = 0.02
MELODY_GAP_S = 0.3


class RealTimeRobot:
    """Plant + sensors + FakeEV3 in ``root``, advanced by :meth:`step` at wall-clock times."""

    def __init__(self, sc, root, params=None, hold_s=DEFAULT_HOLD_S, say=None, stand=False, hang=False):
        self.sc = sc
        nominal = load_params() if params is None else params
        p = scaled_params(sc.param_scale, nominal)
        self.model = RobotModel(sc.plant_variant, p)
        to_model = 1.0 / np.diag(state_scale_to_si(self.model.variant))
        self.plant = Plant(self.model, np.array(sc.x0_si) * to_model, dt_s=PLANT_DT_S)
        self.rest_th1 = math.pi if hang else 0.0
        if hang:        # upside down: th1 = pi
            self.plant.x[2] = math.pi
        if stand:       # link 1 held on a stand (the joint swing test; --hang: upside down): hostsim.world.stand
            self.plant.load = Stand(self.model, self.plant.x, dt_s=PLANT_DT_S)
        elif hang:      # the wheels held (the axle swing): d held, link 1 free
            self.plant.load = Stand(self.model, self.plant.x, held=(0, 1))
        self.config = firmware_config(sc, nominal["rw_m"])
        s = sc.sensors
        self.battery_v = s.battery_v
        self.rng = np.random.default_rng(sc.seed)
        signs = tuple(self.config["polarity"][r] for r in MOTOR_ROLES)
        self.sensors = SensorModel(p["rw_m"], motor_signs=signs, gyro_sign=int(s.gyro_sign),
                                   gyro_bias_dps=s.gyro_bias_dps, gyro_noise_dps=s.gyro_noise_dps,
                                   rng=self.rng, battery_v=self.battery_v)
        self.ports = tuple(self.config["ports"][r] for r in MOTOR_ROLES)
        if self.ports != DEFAULT_MOTOR_PORTS:
            raise ValueError("the fake EV3 has its motors on %s" % (DEFAULT_MOTOR_PORTS,))
        self.fake = FakeEV3(root_dir=root, battery_v=self.battery_v)
        self.hold_s = hold_s
        self.say = say
        self.x0 = self.plant.x.copy()
        self._pick_up()
        self.t_s = 0.0
        self.t_run_start_s = None       # the current firmware run's start-up (motors to run-direct)
        self.t_gyro_mode_s = None
        self.events = []                # what happened to each firmware run, one line each
        self.volts = np.zeros(5)
        self.max_abs_th1 = 0.0
        self.trace_t, self.trace_x, self.trace_u = [], [], []
        self.lights = self.fake.lights()
        self.tones_heard, self.notes, self.t_note_s, self.t_signals_s = 0, [], 0.0, 0.0
        self._publish()

    def _publish(self):
        enc, gyro, volts = self.sensors.read(self.plant.x_si, self.t_s)
        self.fake.set_readings(enc, gyro, volts)

    def _pick_up(self):
        """The owner puts the robot back at the start pose and holds it there."""
        self.plant.x = self.x0.copy()
        self.pushes = sorted((q.t_s, q.th1_dot_rad_s) for q in self.sc.pushes)
        self.fallen = False
        self.t_release_s = None

    def _run_boundaries(self, t_s, states):
        running = any(states[p].running for p in self.ports)
        if running and self.t_run_start_s is None:
            if self.t_release_s is not None:
                self._event("a firmware run starts at %.3f s: the robot is picked up%s and held at the start pose"
                            % (t_s, " from the floor" if self.fallen else ""))
                self._pick_up()
            self.t_run_start_s = t_s
        elif not running and self.t_run_start_s is not None:
            self._event("the firmware run that started at %.3f s stopped its motors at %.3f s: %s"
                        % (self.t_run_start_s, t_s, self.release_text()))
            self.t_run_start_s = None

    def release_text(self):
        return "%s%s" % ("never released" if self.t_release_s is None else "released at %.3f s" % self.t_release_s,
                         ", FELL" if self.fallen else "")

    def _watch_signals(self, t_s):
        """Say what the brick shows: its lights when they change, a melody's notes once it ended."""
        self.t_signals_s = t_s
        lights = self.fake.lights()
        if lights != self.lights:
            self.lights = lights
            self._tell("lights: left %(left)s, right %(right)s" % lights)
        tones = self.fake.tones(self.tones_heard)
        self.tones_heard += len(tones)
        if tones:
            self.notes += [hz for _, hz in tones if hz]
            self.t_note_s = t_s
        elif self.notes and t_s - self.t_note_s > MELODY_GAP_S:
            self._tell("sound: %s Hz" % " ".join(str(hz) for hz in self.notes))
            self.notes = []

    def _tell(self, text):
        if self.say:
            self.say(text)

    def _event(self, text):
        self.events.append(text)
        self._tell(text)

    def step(self, t_s):
        """Advance to wall-clock time t_s (s since start) and publish the readings there."""
        states = self.fake.poll(t_s)
        self._run_boundaries(t_s, states)
        duties = [states[p].duty if states[p].running else 0 for p in self.ports]
        if self.t_gyro_mode_s is None and self.fake.gyro_mode == "GYRO-G&A":
            self.t_gyro_mode_s = t_s
        if self.t_release_s is None:
            if any(duties) or (self.t_run_start_s is not None and t_s - self.t_run_start_s >= self.hold_s):
                self.t_release_s = t_s
        elif not self.fallen and t_s > self.t_s:
            t_rel = self.t_s - self.t_release_s
            while self.pushes and self.pushes[0][0] <= t_rel:
                self.plant.x[7] += self.pushes.pop(0)[1]
            u = self.volts + np.array(disturbance_at(self.sc, t_rel))
            self.plant.advance(u, t_s - self.t_s)
            x = self.plant.x_si
            self.max_abs_th1 = max(self.max_abs_th1, abs(x[2]))
            self.trace_t.append(t_s)
            self.trace_x.append(x)
            self.trace_u.append(u)
            if abs(x[2] - self.rest_th1) > FALLEN_RAD:
                self.fallen = True
                self.plant.x[5:] = 0.0
        # the voltages the firmware's duties give, held until the next poll
        signs = self.sensors.motor_signs
        v = np.zeros(5)
        for i, d in enumerate(duties):
            v[ACTUATED_INPUTS[i]] = signs[i] * d / 100.0 * self.battery_v
        self.volts = v
        self.t_s = t_s
        self._publish()
        if t_s - self.t_signals_s >= SIGNALS_EVERY_S:
            self._watch_signals(t_s)

    def save_trace(self, path):
        np.savez(path, t_s=np.array(self.trace_t), x_si=np.array(self.trace_x).reshape(-1, 10),
                 u_v=np.array(self.trace_u).reshape(-1, 5),
                 t_release_s=np.nan if self.t_release_s is None else self.t_release_s)

    def close(self):
        self.fake.close()


def run_realtime(robot, duration_s=None, step_s=DEFAULT_STEP_S, stop=lambda: False):
    """Drive ``robot`` on the wall clock until duration_s (None: until stop() is true).
    -> dict of loop statistics."""
    t0 = time.monotonic()
    steps = 0
    worst = 0.0
    last = 0.0
    while not stop():
        now = time.monotonic() - t0
        if duration_s is not None and now >= duration_s:
            break
        robot.step(now)
        steps += 1
        worst = max(worst, now - last)
        last = now
        rest = step_s - (time.monotonic() - t0 - now)
        if rest > 0:
            time.sleep(rest)
    elapsed = time.monotonic() - t0
    return {"steps": steps, "elapsed_s": elapsed, "mean_step_s": elapsed / max(steps, 1),
            "max_step_s": worst}


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("fake-robot"),
                                 description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", required=True, metavar="DIR",
                    help="directory for the fake sysfs tree (absent or empty); the firmware's --sysfs-root")
    ap.add_argument("--scenario", metavar="FILE", help="hostsim scenario (file or name under scenarios/); "
                    "used: x0_si, pushes, disturbances, plant_variant, param_scale, sensors, seed")
    ap.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: at SIGTERM/SIGINT)")
    ap.add_argument("--step-ms", type=float, default=DEFAULT_STEP_S * 1e3, help="loop period (default 1 ms)")
    ap.add_argument("--hold-s", type=float, default=DEFAULT_HOLD_S,
                    help="release the robot this long after the firmware's start-up at the latest (default %g)"
                    % DEFAULT_HOLD_S)
    ap.add_argument("--write-config", metavar="FILE", help="write the matching firmware configuration to FILE")
    ap.add_argument("--stand", action="store_true", help="link 1 held upright on a stand; with --hang, upside "
                    "down (for the joint swings, python3 -m tipbot_fw swing-test --joint 2 or 3)")
    ap.add_argument("--hang", action="store_true", help="the robot upside down, held by its wheels (for the axle "
                    "swing, python3 -m tipbot_fw swing-test --joint 1); with --stand, link 1 held upside down (for "
                    "swing-test --joint 2 and 3)")
    ap.add_argument("--trace", metavar="FILE", help="save the plant's true trajectory (npz) at the end")
    a = ap.parse_args(argv)
    try:
        sc = load_scenario(a.scenario) if a.scenario else parse_scenario({}, "<default scenario>")
        robot = RealTimeRobot(sc, a.root, hold_s=a.hold_s, say=lambda m: print("fake_robot: " + m, flush=True),
                              stand=a.stand, hang=a.hang)
    except (TipbotError, ConfigError, FakeEV3Error) as e:     # a scenario the firmware could not be told
        print("fake_robot: error: %s" % e, file=sys.stderr)
        return 2
    stopping = []

    def on_signal(signum, frame):
        stopping.append(signum)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        if a.write_config:
            with open(a.write_config, "w") as f:
                json.dump(robot.config, f, indent=1, sort_keys=True)
        print("fake_robot: ready, sysfs root %s (scenario %s)" % (robot.fake.sysfs_root, sc.name), flush=True)
        stats = run_realtime(robot, a.duration, a.step_ms * 1e-3, stop=lambda: bool(stopping))
    finally:
        robot.close()
        if a.trace:
            robot.save_trace(a.trace)
    print("fake_robot: stopped after %.2f s: %s, max |th1| %.4f rad; %d steps, mean %.2f ms, max %.2f ms"
          % (stats["elapsed_s"], robot.release_text(), robot.max_abs_th1,
             stats["steps"], stats["mean_step_s"] * 1e3, stats["max_step_s"] * 1e3), flush=True)
    if robot.fake.errors:
        print("fake_robot: client errors: %s" % "; ".join(robot.fake.errors[:5]), flush=True)
    return 0

