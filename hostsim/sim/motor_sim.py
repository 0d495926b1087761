"""A DC motor with known parameters behind one port of the fake EV3, for motor identification.

The motor (output-shaft quantities, SI, as in Table 2 of the paper)::

    J w' = Km i - beta w - Tc sgn(w),    i = (u - Ke w) / Ra      (inductance neglected)

driven from what a client wrote into the fake sysfs tree (hostsim.world.fake_ev3.FakeEV3.poll):

* ``run-direct`` at duty d (percent): u = d/100 x the battery's terminal voltage;
* ``stop`` with stop_action ``coast``: open circuit, i = 0 (no back-EMF braking);
* ``stop`` with ``brake`` or ``hold``: short circuit, u = 0 (back-EMF braking).

The battery (a real EV3's: about 7.5-8.2 V; hostsim.world.sensors.BatteryModel, the robot's)
has an internal resistance ``battery_r_ohm`` and the brick draws ``idle_current_a``: with the
motor's current the terminal voltage sags, Vb = V0 - R (I0 + d i). Driven, the motor then sees a resistance Ra + R d^2 and a source
d (V0 - R I0): still a first-order system, integrated exactly (no step-size error) between
the fake's polls, so a wrong fit cannot hide behind integration error. The fake publishes
``voltage_now`` (with ``battery_noise_v`` of seeded Gaussian noise, as an ADC reads it) and
``position``: the shaft angle in whole degrees (floor, from a seeded random encoder phase;
360 counts per turn), as the tacho counts it.

Two ways to run it:

* lock-step, in one process: :func:`simulate_identify` runs the firmware's identify command
  (tipbot_fw.identify.run_identify, through its real sysfs device layer) with a
  ``VirtualClock`` whose sleeps advance the motor; deterministic (what the tests use);
* real time, for the firmware as a separate process (``python3 -m tipbot_fw identify
  --sysfs-root DIR``)::

      python -m hostsim motor-sim --root /tmp/ev3 --motor 5 --realtime &
      python3 -m tipbot_fw identify --port outA --yes --sysfs-root /tmp/ev3 --log m5.log

  (the duty takes effect at the first poll after the firmware wrote it, 0-1 ms late: an
  apparent dead time the host fit estimates).

``python -m hostsim motor-sim --motor 1 --log FILE`` writes a simulated identify log (lock-step).
"""
import argparse
import math
import os
import signal
import tempfile
import time

import hostsim
import numpy as np

from hostsim.model.motors import TABLE2, TABLE2_DRIVER, MotorParams
from hostsim.world.fake_ev3 import FakeEV3
from hostsim.world.sensors import BatteryModel
from tipbot_fw.io.clock import VirtualClock

DEFAULT_BATTERY_V = 8.0
DEFAULT_BATTERY_R_OHM = 0.1
DEFAULT_IDLE_CURRENT_A = 0.15
DEFAULT_BATTERY_NOISE_V = 0.003


class DCMotor:
    """Shaft angle and speed, advanced exactly for a constant drive: J w' = a - b w - Tc sgn(w)."""

    def __init__(self, params, theta_rad=0.0, omega_rad_s=0.0):
        self.p = params
        self.theta = float(theta_rad)
        self.omega = float(omega_rad_s)

    def advance(self, dt, a, b):
        """a: drive torque (N m), b: total viscous coefficient (N m s), for dt seconds."""
        j, tc = self.p.jm_kg_m2, self.p.coulomb_nm
        while dt > 0.0:
            w0 = self.omega
            if w0 == 0.0:
                if abs(a) <= tc:          # static friction holds it
                    return
                s = math.copysign(1.0, a)
            else:
                s = math.copysign(1.0, w0)
            drive = a - tc * s
            if b > 0.0:
                w_inf = drive / b
                tau = j / b
                t_cross = math.inf
                if w0 != 0.0 and w_inf * w0 < 0.0:      # heading through zero
                    t_cross = tau * math.log((w0 - w_inf) / (-w_inf))
                h = min(dt, t_cross)
                e = math.exp(-h / tau)
                self.theta += w_inf * h + (w0 - w_inf) * tau * (1.0 - e)
                self.omega = w_inf + (w0 - w_inf) * e
            else:
                acc = drive / j
                t_cross = -w0 / acc if w0 != 0.0 and acc * w0 < 0.0 else math.inf
                h = min(dt, t_cross)
                self.theta += w0 * h + 0.5 * acc * h * h
                self.omega = w0 + acc * h
            if h == t_cross:
                self.omega = 0.0
            dt -= h


class FakeMotorBench:
    """The motor on one port of a FakeEV3 and the EV3 battery; :meth:`advance` is a
    VirtualClock ``on_sleep``: the client's writes (seen by one poll) act from t_from."""

    def __init__(self, fake, port, params, battery_v=DEFAULT_BATTERY_V, battery_r_ohm=DEFAULT_BATTERY_R_OHM,
                 idle_current_a=DEFAULT_IDLE_CURRENT_A, battery_noise_v=DEFAULT_BATTERY_NOISE_V, seed=0):
        self.fake = fake
        self.port = port
        self.p = params
        self.motor = DCMotor(params)
        self.battery = BatteryModel(battery_v, battery_r_ohm, ke_v_s=(params.ke_v_s,), ra_ohm=(params.ra_ohm,),
                                    idle_a=idle_current_a)
        self.noise_v = float(battery_noise_v)
        self.rng = np.random.default_rng(seed)
        self.encoder_phase = float(self.rng.uniform(0.0, 1.0))   # fraction of a count at angle 0
        self.t = 0.0
        self.state = None
        self.trace = []            # (t, theta, omega, terminal volts, mode)
        self.poll()
        self.publish()

    # -- what the client commanded
    def poll(self):
        self.state = self.fake.poll()[self.port]
        return self.state

    def mode(self):
        st = self.state
        if st.running:
            return "drive"
        if st.command == "stop" and st.stop_action in ("brake", "hold"):
            return "brake"
        return "coast"

    def _drive(self):
        """-> (a, b, duty fraction) of the current mode (see the module docstring)."""
        p = self.p
        mode = self.mode()
        if mode == "drive":
            d = self.state.duty / 100.0
            v_src, r_more = self.battery.source(d)
            ra_eff = p.ra_ohm + r_more
            return p.km_nm_a * v_src / ra_eff, p.km_nm_a * p.ke_v_s / ra_eff + p.beta_nm_s, d
        if mode == "brake":
            return 0.0, p.km_nm_a * p.ke_v_s / p.ra_ohm + p.beta_nm_s, 0.0
        return 0.0, p.beta_nm_s, 0.0

    def terminal_v(self):
        """Battery terminal voltage now (without the reading noise)."""
        d = self.state.duty / 100.0 if self.mode() == "drive" else 0.0
        return self.battery.voltage([d], [self.motor.omega])

    # -- time
    def advance(self, t_from, t_to):
        self.poll()
        if t_to > self.t:
            a, b, _ = self._drive()
            self.motor.advance(t_to - self.t, a, b)
            self.t = t_to
        self.publish()

    def publish(self):
        deg = math.degrees(self.motor.theta)
        counts = math.floor(deg + self.encoder_phase)
        self.fake.set_encoder_counts(self.port, counts, speed=round(math.degrees(self.motor.omega)))
        vb = self.terminal_v()
        self.fake.set_battery_v(vb + (self.rng.normal(0.0, self.noise_v) if self.noise_v > 0 else 0.0))
        self.trace.append((self.t, self.motor.theta, self.motor.omega, vb, self.mode()))


def one_motor_fake(port, driver, root_dir=None, battery_v=DEFAULT_BATTERY_V):
    """A FakeEV3 with only ``driver`` on ``port`` (no gyro): polls stay cheap."""
    motors = {p: None for p in ("outA", "outB", "outC", "outD")}
    motors[port] = driver
    return FakeEV3(root_dir=root_dir, battery_v=battery_v, motors=motors, gyro_port=None)


def simulate_identify(params, log_path, driver="lego-ev3-l-motor", port="outA", duty=100, seconds=2.0,
                      rundown_seconds=4.0, still_seconds=0.3, period_s=0.0005, battery_v=DEFAULT_BATTERY_V,
                      battery_r_ohm=DEFAULT_BATTERY_R_OHM, idle_current_a=DEFAULT_IDLE_CURRENT_A,
                      battery_noise_v=DEFAULT_BATTERY_NOISE_V, seed=0, header_extra=None, blocked=False, hook=None):
    """The firmware's identify run (tipbot_fw.identify, through its sysfs device layer) on the
    fake motor, in lock-step with a virtual clock. period_s: time between two position reads
    (the firmware reads as fast as it can on the brick; here each read costs period_s).
    blocked: the shaft cannot turn (a stalled motor). hook(t_from, t_to, bench), if given, is
    called after each advance (tests inject signals and failures). -> (exit code, log header, bench)."""
    from tipbot_fw.identify import SingleMotor, run_identify
    if period_s <= 0:
        raise ValueError("period_s must be > 0 with the virtual clock (time moves only in its sleeps)")
    if blocked:
        params = params._replace(coulomb_nm=1e3)
    fake = one_motor_fake(port, driver, battery_v=battery_v)
    try:
        bench = FakeMotorBench(fake, port, params, battery_v, battery_r_ohm, idle_current_a, battery_noise_v, seed)
        def on_sleep(t_from, t_to):
            bench.advance(t_from, t_to)
            if hook is not None:
                hook(t_from, t_to, bench)
        clock = VirtualClock(on_sleep=on_sleep)
        motor = SingleMotor(port, sysfs_root=fake.sysfs_root, io=fake.io)
        try:
            extra = {"simulated": {"params": dict(params._asdict()), "phi": params.phi, "alpha": params.alpha,
                                   "battery_v": battery_v, "battery_r_ohm": battery_r_ohm, "seed": seed}}
            extra.update(header_extra or {})
            code, header = run_identify(motor, clock, duty=duty, seconds=seconds, rundown_seconds=rundown_seconds,
                                        still_seconds=still_seconds, period_s=period_s, log_path=log_path,
                                        header_extra=extra, say=lambda msg: None)
        finally:
            motor.close()
        bench.poll()
        return code, header, bench
    finally:
        fake.close()


class RealTimeBench:
    """FakeMotorBench on the wall clock, for the firmware in another process."""

    def __init__(self, root, port, driver, params, **kw):
        self.fake = one_motor_fake(port, driver, root_dir=root, battery_v=kw.get("battery_v", DEFAULT_BATTERY_V))
        self.bench = FakeMotorBench(self.fake, port, params, **kw)

    def run(self, duration_s=None, step_s=0.0005, stop=lambda: False):
        t0 = time.monotonic()
        steps = 0
        while not stop():
            now = time.monotonic() - t0
            if duration_s is not None and now >= duration_s:
                break
            self.bench.advance(self.bench.t, now)
            steps += 1
            rest = step_s - (time.monotonic() - t0 - now)
            if rest > 0:
                time.sleep(rest)
        return steps

    def close(self):
        self.fake.close()


def _params_from_args(a):
    p = TABLE2[a.motor]
    over = {k: getattr(a, k) for k in p._fields if getattr(a, k, None) is not None}
    return p._replace(**over)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("motor-sim"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--motor", type=int, choices=sorted(TABLE2), default=1, help="Table 2 motor (default 1)")
    for name in MotorParams._fields:
        ap.add_argument("--" + name.replace("_", "-"), dest=name, type=float, help="override Table 2's " + name)
    ap.add_argument("--driver", help="ev3dev driver (default: large motor for 1-4, medium for 5)")
    ap.add_argument("--port", default="outA", help="the motor's port (default outA)")
    ap.add_argument("--battery-v", type=float, default=DEFAULT_BATTERY_V,
                    help="open-circuit battery voltage (default %g)" % DEFAULT_BATTERY_V)
    ap.add_argument("--seed", type=int, default=0, help="seed of the encoder phase and battery noise")
    ap.add_argument("--log", metavar="FILE", help="lock-step: write a simulated identify log here")
    ap.add_argument("--duty", type=int, default=100, help="lock-step: duty in percent (default 100)")
    ap.add_argument("--seconds", type=float, default=2.0, help="lock-step: drive time in s (default 2)")
    ap.add_argument("--period-ms", type=float, default=0.5, help="lock-step: time between reads (default 0.5)")
    ap.add_argument("--realtime", action="store_true", help="keep a fake EV3 tree in --root in step with the "
                    "motor on the wall clock until SIGTERM/SIGINT or --duration")
    ap.add_argument("--root", metavar="DIR", help="--realtime: the fake sysfs tree's directory (absent or empty)")
    ap.add_argument("--duration", type=float, help="--realtime: stop after this many seconds")
    a = ap.parse_args(argv)
    params = _params_from_args(a)
    driver = a.driver or TABLE2_DRIVER[a.motor]
    if a.realtime:
        if not a.root:
            ap.error("--realtime needs --root DIR")
        stopping = []
        signal.signal(signal.SIGTERM, lambda s, f: stopping.append(s))
        signal.signal(signal.SIGINT, lambda s, f: stopping.append(s))
        rt = RealTimeBench(a.root, a.port, driver, params, battery_v=a.battery_v, seed=a.seed)
        try:
            print("motor_sim: ready, sysfs root %s: %s on %s (phi %.4g rad/s/V, alpha %.4g s)"
                  % (rt.fake.sysfs_root, driver, a.port, params.phi, params.alpha), flush=True)
            steps = rt.run(a.duration, stop=lambda: bool(stopping))
        finally:
            rt.close()
        print("motor_sim: stopped after %d steps" % steps, flush=True)
        return 0
    log = a.log or os.path.join(tempfile.gettempdir(), "identify-sim-motor%d.log" % a.motor)
    code, header, _ = simulate_identify(params, log, driver=driver, port=a.port, duty=a.duty, seconds=a.seconds,
                                        period_s=a.period_ms * 1e-3, battery_v=a.battery_v, seed=a.seed)
    print("motor_sim: motor %d (%s, phi %.4g rad/s/V, alpha %.4g s, Jm/beta %.4g s): exit %d, %d rows -> %s"
          % (a.motor, driver, params.phi, params.alpha, params.tau_coast_s, code, header.get("rows", 0), log))
    return 0 if code == 0 else 1

