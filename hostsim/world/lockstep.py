"""The worlds of a firmware-in-the-loop run (hostsim.sim.firmware_run): the plant, the sensors and
the fake EV3, advanced by the firmware's clock whenever its loop sleeps.

:class:`World` is the ideal brick's: reads at the tick's start, all duties together
``io_latency_s`` later, ideal sensors and motors. :class:`BrickWorld` (a scenario's ``brick``
effects) runs the same plant on a fixed 1 ms grid (k * dt from the start of the run) and adds what the scenario's ``brick``
switches on:

- the drivetrain (hostsim.world.drivetrain: rotors, Coulomb friction, backlash), encoders
  updated every 2 ms and truncated, the gyro's latency, freezes, scale error, drift and steps
  (hostsim.world.gyro), the battery's sag and quantization (hostsim.world.sensors);
- with the brick's timing (``brick.timed``), time that costs (hostsim.world.brick_timing):
  each sysfs read samples the world at its own moment, each duty reaches its motor at the
  moment of its write, the tick's compute time, late wake-ups and stalls; without it, the
  reads see the tick's start and the duties land together ``io_latency_s`` into the tick
  (plus ``extra_delay_ticks``, ``jitter_s``), as in World.

Within a 1 ms step the inputs are held (zero-order) except where a duty lands inside it:
that step gets each motor's duty averaged over the step, which gives the step the exact
impulse of the motor torque (linear in the voltage); the application times themselves are
kept exactly (``duty_events``). Sensor values are those of the last grid step at or before
the moment they are sampled (the gyro sends about one message per millisecond, encoders
latch every 2 ms).

Start: the plant is held at the scenario's start pose during the firmware's gyro
calibration (the sensors keep running: bias drift, the gyro's own integration) and released
when the control loop starts: without the timing at ``t_release_s`` as in World; with it, at
the first read of the loop's first tick (the reads are counted: the calibration reads the
devices ``calibration_reads`` times).
"""
import numpy as np

from hostsim.world.plant import apply_push, disturbance_at
from tipbot_fw.vocabulary import ACTUATED_INPUTS

DEFAULT_IO_LATENCY_S = 0.002
PLANT_DT_S = 0.001
_EPS_S = 1e-9


class Lockstep(object):
    """What a world does when the firmware's loop sleeps, whichever world: the release, the
    marks between iterations in the fake's I/O log, the wake-up jitter, the records. Needs
    sc, fake, rng, clock, t_release_s, released, io_marks, log_t, log_x, plant."""

    def _wake(self, t_from, t_to, dt):
        """A loop iteration ended at t_from and sleeps until t_to: release the plant at the
        first one, mark the I/O log, make the wake-up late by |N(0, jitter_s)| (whole plant
        steps of dt). -> (t_from, t_to) as they are."""
        t_from = max(t_from, self.t_release_s)
        if not self.released:
            self.released = True
            self._record(t_from)
        if self.fake is not None:
            # Where each loop iteration's sysfs operations end in the fake's client-I/O log.
            self.io_marks.append(len(self.fake.io.log))
        if self.sc.jitter_s > 0:
            late = abs(self.rng.normal(0.0, self.sc.jitter_s))
            t_to = t_to + round(late / dt) * dt
            self.clock.t = t_to
        return t_from, t_to

    def _record(self, t):
        self.log_t.append(t - self.t_release_s)
        self.log_x.append(self.plant.x_si)


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


class BrickWorld(Lockstep):
    """Plant + sensor models (+ fake EV3) on a 1 ms grid, advanced by the firmware's clock.

    plant: a Plant or DrivetrainPlant; encoders: EncoderModel; gyro: GyroModel, or None for
    SensorModel's ideal gyro (``sensors``); battery: BatteryModel; signs: the motors' physical
    directions (+1/-1, config polarity); times: AccessTimes with the brick's timing, else None.
    """

    def __init__(self, sc, plant, sensors, encoders, gyro, battery, signs, ts_s, t_release_s, calibration_reads,
                 fake=None, ports=None, rng=None, times=None):
        self.sc = sc
        self.plant = plant
        self.dt = plant.dt_s
        self.sensors = sensors
        self.encoders = encoders
        self.gyro = gyro
        self.battery = battery
        self.signs = tuple(signs)
        self.ts_s = ts_s
        self.t_release_s = t_release_s
        self.calibration_reads = calibration_reads
        self.fake = fake
        self.ports = ports
        self.rng = rng
        self.times = times
        self.timed = times is not None
        self.devices = None
        self.clock = None
        self.k = 0                      # grid steps integrated: the plant is at k * dt
        self.k_release = None           # the first step the plant moves in
        self.released = False
        self.frac = [0.0] * 4           # duty fraction applied per motor (model direction)
        self.changes = []               # (t, motor, fraction) landing in the current step
        self.duty_events = []           # (t from release, motor, duty): every application
        self.delay = [[0.0] * 4] * sc.extra_delay_ticks
        self.pushes = sorted(sc.pushes, key=lambda p: p.t_s)
        self.battery_v = battery.v_oc
        self.readings = None
        self.read_cycles = 0
        self.log_t, self.log_x, self.log_u, self.log_w = [], [], [], []
        self.io_marks = []
        self.first_port_position = None
        if fake is not None and ports:
            self.first_port_position = fake.relpath(ports[0], "position")
            self._port_index = {fake.relpath(p, "position"): i for i, p in enumerate(ports)}
            self._duty_index = {}
            for i, p in enumerate(ports):
                self._duty_index[fake.relpath(p, "duty_cycle_sp")] = i
                self._duty_index[fake.relpath(p, "command")] = i
        if not self.timed:
            self.k_release = int(round(t_release_s / self.dt))
        self.publish(0.0)

    # ------------------------------------------------------------------ the grid
    def _t(self, k):
        return k * self.dt

    def catch_up(self, t):
        """Integrate every grid step that ends at or before t."""
        while self._t(self.k + 1) <= t + _EPS_S:
            self._step()

    def _moving(self, k):
        return self.k_release is not None and k >= self.k_release

    def _step(self):
        k = self.k
        t0, t1 = self._t(k), self._t(k + 1)
        plant = self.plant
        if self._moving(k):
            rel0 = t0 - self.t_release_s
            while self.pushes and self.pushes[0].t_s <= rel0 + _EPS_S:
                apply_push(plant, self.pushes.pop(0))
            fr = self._step_fractions(t0, t1) if self.changes else self.frac
            v = self._battery_now() if self.battery.r else self.battery_v
            u = [fr[0] * v, fr[1] * v, 0.0, fr[2] * v, fr[3] * v]     # ACTUATED_INPUTS
            if self.sc.disturbances:
                w = disturbance_at(self.sc, 0.5 * (t0 + t1) - self.t_release_s)
                u = [a + b for a, b in zip(u, w)]
            plant.advance(u, self.dt)
        elif self.changes:
            self._step_fractions(t0, t1)
        self.k = k = k + 1
        enc = self.encoders
        if enc.every and k % enc.every == 0:
            enc.on_step(k, plant.motor_angles())
        if self.gyro is not None:
            self.gyro.on_step(t1, float(plant.x[7]))     # rad/s in every variant

    def _step_fractions(self, t0, t1):
        """Each motor's duty fraction averaged over the step [t0, t1] (the changes inside it
        applied at their moments), leaving the last ones applied."""
        acc = [f * 0.0 for f in self.frac]
        last = [t0] * 4
        frac = list(self.frac)
        for t, i, f in self.changes:
            acc[i] += frac[i] * (t - last[i])
            last[i] = t
            frac[i] = f
        out = [(acc[i] + frac[i] * (t1 - last[i])) / (t1 - t0) for i in range(4)]
        self.frac = frac
        self.changes = []
        return out

    def _battery_now(self):
        v = self.battery_v = self.battery.voltage(self.frac, self.plant.motor_speeds())
        return v

    def _apply(self, t, i, frac):
        self.changes.append((t, i, frac))
        self.duty_events.append((t - self.t_release_s, i, frac))

    # ------------------------------------------------------------------ what the firmware sees
    def _encoder_counts(self):
        return self.encoders.read(self.plant.motor_angles())

    def _gyro_now(self, t):
        if self.gyro is not None:
            return self.gyro.read(t)
        return self.sensors.gyro(self.plant.x_si, t)

    def publish(self, t):
        """Every reading as of t (the untimed world: the reads see the tick's start)."""
        enc, gyro = self._encoder_counts(), self._gyro_now(t)
        volts = self.battery_reading()
        self.readings = (enc, gyro)
        if self.fake is not None:
            self.fake.poll(t)
            self.fake.set_readings(enc, gyro, volts)

    def read(self):
        """MemoryDevices source (untimed only)."""
        return self.readings

    def battery_reading(self):
        """What voltage_now says now."""
        return self.battery.reading(self.battery_v)

    def loop_running(self):
        return self.released

    def sample(self, rel, t):
        """TimedIO: publish the attribute about to be read, as of t."""
        if rel == self.first_port_position:
            self.read_cycles += 1
            if self.read_cycles == self.calibration_reads + 1:
                self._release(t)
        self.catch_up(t)
        i = self._port_index.get(rel)
        fake = self.fake
        fake.set_time(t)
        if i is not None:
            fake.set_encoder_counts(self.ports[i], self._encoder_counts()[i])
        elif rel.endswith("bin_data"):
            angle, rate = self._gyro_now(t)
            fake.set_gyro(angle, rate)
        elif rel.endswith("voltage_now"):
            fake.set_battery_v(self.battery_reading())

    def wrote(self, rel, t):
        """TimedIO: a client's write lands at t."""
        self.catch_up(t)
        port = self.fake.poll_attribute(rel, t)
        i = self._duty_index.get(rel)
        if port is not None and i is not None:
            frac = self.signs[i] * self.fake.motor_duty(port) / 100.0
            if frac != self._latest(i):
                self._apply(t, i, frac)

    def _latest(self, i):
        """Motor i's fraction after the changes pending in this step."""
        f = self.frac[i]
        for _, j, g in self.changes:
            if j == i:
                f = g
        return f

    def start_at(self, t0):
        """The firmware's calibration starts at t0 (after its set-up): the untimed world
        releases the plant t_release_s later."""
        if not self.timed:
            self.t_release_s += t0
            self.k_release = int(round(self.t_release_s / self.dt))

    def _release(self, t):
        self.catch_up(t)
        self.t_release_s = t
        self.k_release = self.k
        self.released = True
        self._record(t)

    # ------------------------------------------------------------------ what the firmware commands
    def _commanded(self):
        """The duty fractions the device holds now (model direction)."""
        if self.fake is not None:
            states = self.fake.poll()
            duties = [states[p].duty if states[p].running else 0 for p in self.ports]
        else:
            duties = self.devices.duties
        return [s * d / 100.0 for s, d in zip(self.signs, duties)]

    # ------------------------------------------------------------------ time
    def on_sleep(self, t_from, t_to):
        if self.timed:
            self._sleep_timed(t_from, t_to)
        else:
            self._sleep_untimed(t_from, t_to)

    def _sleep_timed(self, t_from, t_to):
        wake = max(t_from, t_to)
        wake += self.times.wake_delay(wake)
        self.clock.t = wake
        if not self.released:
            self.catch_up(wake)
            return
        self.io_marks.append(len(self.fake.io.log))
        self.catch_up(t_from)
        self._tick_done(t_from)
        self.catch_up(wake)
        self._record(wake)

    def _sleep_untimed(self, t_from, t_to):
        if t_to <= self.t_release_s + _EPS_S:        # held still while calibrating
            self.catch_up(t_to)
            self.publish(t_to)
            return
        t_from, t_to = self._wake(t_from, t_to, self.dt)
        self.delay.append(self._commanded())
        new = self.delay.pop(0)
        t_switch = min(t_from + self.sc.io_latency_s, t_to)
        self.catch_up(t_switch)
        for i in range(4):
            if new[i] != self.frac[i]:
                self._apply(t_switch, i, new[i])
        self.catch_up(t_to)
        self._tick_done(t_to)
        self._record(t_to)
        self.publish(t_to)

    def _tick_done(self, t):
        """The inputs of the tick that ends at t, for the results."""
        self.log_u.append(self._volts_after_changes())
        self.log_w.append(np.array(disturbance_at(self.sc, t - self.t_release_s - 0.5 * self.ts_s)))

    def _volts_after_changes(self):
        v = [0.0] * 5
        for i in range(4):
            v[ACTUATED_INPUTS[i]] = self._latest(i) * self.battery_v
        return np.array(v)
