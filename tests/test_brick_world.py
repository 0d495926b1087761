"""The unkind brick in the loop (hostsim.world.lockstep, hostsim.world.brick_timing): time that
costs, staggered duties, the firmware's own overrun accounting, the fake EV3's blocking and
failing mode writes, the battery's sag in the firmware's log, the realistic preset."""
import dataclasses
import errno
import math

import numpy as np
import pytest

from hostsim.sim.firmware_build import SimulationError
from hostsim.sim.firmware_run import run_firmware
from hostsim.sim.scenario import Brick, load_scenario
from hostsim.studies.montecarlo import gains_document
from hostsim.world.brick_timing import AccessTimes, BrickClock, TimedIO
from hostsim.world.fake_ev3 import GYRO_MODE_TRIES, GYRO_MODE_TRY_S, FakeEV3
from tipbot_fw.io import lights_speaker
from tipbot_fw.record import logfile
from tipbot_fw.config import defaults
from tipbot_fw.io.ev3dev import Ev3Devices, Ev3SetupError
from tipbot_fw import vocabulary

TACHO = (0.0003, 0.00045)


def scenario(duration_s=0.4, th1=0.05, **brick):
    sc = load_scenario("near_equilibrium")
    x0 = [0.0] * 10
    x0[2] = th1
    return dataclasses.replace(sc, duration_s=duration_s, x0_si=tuple(x0), brick=Brick(**brick))


def kw0():
    return gains_document(load_scenario("near_equilibrium").gains, True)


class _Recorder(object):
    """A world that notes when TimedIO asks it to sample and apply."""

    def __init__(self):
        self.samples, self.writes = [], []
        self.running = True

    def sample(self, rel, t):
        self.samples.append((rel, t))

    def wrote(self, rel, t):
        self.writes.append((rel, t))

    def loop_running(self):
        return self.running


def timed_devices(fake, times, world):
    clock = BrickClock()
    cfg = defaults()
    io = TimedIO(fake.io, fake, clock, world, times, end_of_reads=fake.relpath("in2", "bin_data"))
    return Ev3Devices(cfg, sysfs_root=fake.sysfs_root, io=io), clock


def test_each_read_samples_the_world_at_its_own_moment_and_the_compute_is_charged():
    brick = Brick(tacho_access_s=(0.0004, 0.0004), sensor_access_s=(0.0001, 0.0001), compute_s=(0.0008, 0.0008))
    world = _Recorder()
    with FakeEV3() as fake:
        dev, clock = timed_devices(fake, AccessTimes(brick, np.random.default_rng(0)), world)
        try:
            t0 = clock.now()
            world.samples.clear()
            world.writes.clear()
            dev.read_raw()
            times = [t - t0 for _, t in world.samples]
            # four positions at the middles of their 0.4 ms, then the gyro in the middle of its 0.1 ms
            assert times == pytest.approx([0.0002, 0.0006, 0.0010, 0.0014, 0.00165])
            assert [rel.rsplit("/", 1)[1] for rel, _ in world.samples] == ["position"] * 4 + ["bin_data"]
            assert clock.t - t0 == pytest.approx(0.0017)        # the compute is not paid yet ...
            assert clock.now() - t0 == pytest.approx(0.0025)    # ... until the next clock reading
            dev.write_duties([10, -20, 30, -40])
            w = [t - t0 for _, t in world.writes]
            assert w == pytest.approx([0.0027, 0.0031, 0.0035, 0.0039])   # four moments, 0.4 ms apart
        finally:
            dev.close()


def test_the_lights_and_the_speaker_cost_brick_time():
    # tipbot_fw.io.lights_speaker's writes in the loop's slack go through the timed I/O like the duties:
    # each costs a sensor-class access, and the fake EV3 shows what was written
    brick = Brick(tacho_access_s=(0.0004, 0.0004), sensor_access_s=(0.0001, 0.0001))
    world = _Recorder()
    with FakeEV3() as fake:
        clock = BrickClock()
        io = TimedIO(fake.io, fake, clock, world, AccessTimes(brick, np.random.default_rng(0)))
        signals = lights_speaker.BrickSignals(fake.sysfs_root, io=io, now=clock.now)
        try:
            t0 = clock.now()
            for target, value in ((1, 255), (3, 255), ("tone", 1047)):
                signals.apply(target, value)
            assert clock.now() - t0 == pytest.approx(0.0003)
            assert [rel.rsplit("/", 2)[-2] for rel, _ in world.writes[-3:]] == [
                "led0:green:brick-status", "led1:green:brick-status", "input-by-path"]
            assert fake.lights() == {"left": "green", "right": "green"}
            assert [hz for _, hz in fake.tones()] == [1047]
            assert fake.tones()[0][0] == pytest.approx(t0 + 0.0002)     # the writer's clock: virtual
        finally:
            signals.close()


@pytest.mark.slow
def test_a_timed_run_gives_the_loops_cues_on_the_fake_brick():
    # the let-go melody's rest and 'balancing' come from the loop's side task, each a timed write
    # (hostsim.sim.firmware_run.SlackCues); the writes land between the loop's ticks
    run = run_firmware(scenario(duration_s=1.5, tacho_access_s=(0.0002, 0.0002)), gains_doc=kw0())
    assert run.completed
    tones, lights = [], []
    for k, ops in enumerate(run.io_per_iteration):
        for op, rel, data in ops:
            if "sound" in rel:
                tones.append((k, lights_speaker.INPUT_EVENT.unpack(data)[-1]))
            elif "leds/" in rel:
                lights.append((k, rel.split("/")[1], data))
    # the let-go melody's second and third notes and its end, then 'balancing' after 1 s (200
    # ticks): the left light's red off (amber -> green), then its note (one write a call)
    assert [hz for _, hz in tones] == [659, 784, 0, 1047, 0]
    assert [(rel, data) for _, rel, data in lights] == [("led0:red:brick-status", b"0\n")]
    assert 190 < lights[0][0] < tones[3][0] < 210


def test_every_duty_lands_at_its_own_moment_in_the_tick():
    run = run_firmware(scenario(tacho_access_s=TACHO, compute_s=(0.0007, 0.0009)), gains_doc=kw0())
    assert run.completed
    by_tick = {}
    starts = run.t_s
    for t, motor, _ in run.duty_events:
        k = int(np.searchsorted(starts, t, side="right")) - 1
        by_tick.setdefault(k, []).append((t - starts[k], motor))
    by_tick.pop(len(starts) - 1, None)          # the last tick's: the motors' stop after the run
    full = [sorted(v) for v in by_tick.values() if len(v) == 4]
    assert len(full) > 5
    for ev in full:
        offsets = [t for t, _ in ev]
        assert [m for _, m in ev] == [0, 1, 2, 3]               # right, left, joint 2, joint 3
        gaps = np.diff(offsets)
        assert np.all(gaps >= TACHO[0] - 1e-9) and np.all(gaps <= TACHO[1] + 1e-9)
        # after 4 tacho reads, the gyro and the compute: 2-4 ms into the tick
        assert 0.002 < offsets[0] and offsets[-1] < 0.0045


def test_the_timed_gyro_reaches_the_firmware_after_its_mode_switch():
    """Reads published at their own moments still see the gyro come out of its mode switch:
    the calibration finds the scenario's bias, and the balancing reads move."""
    sc = scenario(duration_s=0.5, tacho_access_s=TACHO)
    sc = dataclasses.replace(sc, sensors=dataclasses.replace(sc.sensors, gyro_bias_dps=1.5))
    run = run_firmware(sc, gains_doc=kw0())
    assert run.header["calibration"]["gyro_bias_dps"] == pytest.approx(1.5, abs=0.5)
    assert np.ptp(run.xhat[:, 7]) > 0.05     # the filter's th1 rate, from the gyro's reads


def test_the_firmware_sees_real_lateness_and_stops_when_it_falls_behind():
    # each tick's own work (9 tacho accesses, compute, writes) takes about 7 ms of the 5 (a tick of
    # about 5.5 ms, a period lost in 15, is ridden out: the window's longest hold is left aside)
    slow = scenario(duration_s=1.0, tacho_access_s=(0.0008, 0.0009), compute_s=(0.0008, 0.0009))
    run = run_firmware(slow, gains_doc=kw0())
    assert run.exit_code == 7 and run.stop_reason == "overruns"
    assert run.header["stop_message"].startswith("the loop is behind")
    assert run.t_s[-1] < 0.5                        # stopped within the overrun window
    flags = run.flags[np.isfinite(run.flags)].astype(int)
    late = (flags & vocabulary.FLAG_BITS["overrun"]) != 0
    assert late[-1] and late.mean() > 0.5           # the stopping tick ended late, as most did
    assert run.header["loop"]["skipped_periods"] > 0
    # the firmware's own tick time: its reads, compute and writes
    assert np.nanmedian(run.tick_work_s) > 0.005


def test_a_tick_just_within_the_period_is_often_late_but_not_behind():
    # about 4.7 ms of work: most ticks end a little late, dozens in a row (what stopped earlier
    # versions at five), but hardly a period is lost: the run completes
    slow = scenario(duration_s=1.0, tacho_access_s=(0.0006, 0.0007), compute_s=(0.0008, 0.0009))
    run = run_firmware(slow, gains_doc=kw0())
    assert run.completed
    loop = run.header["loop"]
    assert loop["overruns"] > 50 and loop["max_consecutive_overruns"] > 5
    assert loop["skipped_periods"] <= 5 and loop["max_lost_s"] < 0.04
    assert 0.004 < np.nanmedian(run.tick_work_s) < 0.005


def test_interrupts_stretch_every_duration():
    brick = Brick(tacho_access_s=(0.0004, 0.0004), sensor_access_s=(0.0001, 0.0001), compute_s=(0.0008, 0.0008),
                  cpu_steal=0.2)
    times = AccessTimes(brick, np.random.default_rng(0))
    assert times.access(0) == pytest.approx(0.0005) and times.compute() == pytest.approx(0.001)


def test_late_wake_ups_and_stalls():
    times = AccessTimes(Brick(late_wake_probability=1.0, late_wake_s=(0.001, 0.002), stall_rate_hz=2.0,
                              stall_s=(0.02, 0.03)), np.random.default_rng(3))
    delays = [times.wake_delay(0.005 * k) for k in range(2000)]
    assert min(delays) >= 0.001
    assert 10 < len(times.stalls) < 40                          # about 2 per second over 10 s
    wakes = [0.005 * k + d for k, d in enumerate(delays)]
    for start, d in times.stalls:
        k = int(start / 0.005)                                  # the wake-up due before it, or the next
        assert max(wakes[k], wakes[k + 1]) >= start + d - 1e-12   # waits for its end
    assert AccessTimes(Brick(), np.random.default_rng(0)).wake_delay(1.0) == 0.0


def test_a_gyro_mode_write_blocks_and_an_old_sensor_times_out():
    world = _Recorder()
    with FakeEV3(gyro_mode_write_s=0.2) as fake:
        dev, clock = timed_devices(fake, None, world)
        dev.close()
        fake.poll(clock.t)
        assert clock.t == pytest.approx(0.2) and fake.gyro_mode == "GYRO-G&A"
    with FakeEV3(gyro_mode_timeout=True) as fake:
        with pytest.raises(Ev3SetupError) as e:
            timed_devices(fake, None, world)
        assert "mode" in str(e.value) and str(errno.ETIMEDOUT) in str(e.value)
    run = run_firmware(scenario(gyro_mode_timeout=True), gains_doc=kw0())
    assert run.exit_code == 3 and not run.completed and "timed out" in run.header["stop_message"]
    assert GYRO_MODE_TRY_S * GYRO_MODE_TRIES == pytest.approx(0.5)


def test_the_battery_sags_and_reads_in_steps_in_the_firmwares_log(tmp_path):
    path = str(tmp_path / "run.log")
    # read every 0.1 s: the Kalman core has settled the 0.1 rad release within a second, and
    # motors at rest draw nothing
    run = run_firmware(scenario(duration_s=2.5, th1=0.1, battery_r_ohm=0.3, battery_quantum_v=0.00244),
                       gains_doc=kw0(), sysfs=False, log_path=path, config_overrides={"battery_period_s": 0.1})
    assert run.completed
    header, rows = logfile.read_log(path)[:2]
    volts = rows[:, [c["name"] for c in header["columns"]].index("battery_v")]
    assert header["battery_v_start"] == pytest.approx(math.floor(8.0 / 0.00244) * 0.00244)
    assert np.allclose(volts / 0.00244, np.round(volts / 0.00244), atol=1e-6)
    assert volts.min() < header["battery_v_start"] - 0.005     # read under load while it recovers


@pytest.mark.parametrize("brick", [dict(tacho_access_s=TACHO), dict(gyro_mode_timeout=True)])
def test_the_brick_timing_and_mode_writes_need_the_sysfs_device(brick):
    with pytest.raises(SimulationError, match="sysfs device"):
        run_firmware(scenario(**brick), gains_doc=kw0(), sysfs=False)


def test_the_realistic_preset():
    sc = load_scenario("brick_realistic")
    assert sc.duration_s == 30 and sc.x0_si[2] == 0.017
    assert sc.firmware_config["start_pose_rad"]["th1"] == 0.0 and sc.modes == ("firmware",)
    b = sc.brick
    assert b.timed and b.drivetrain and b.gyro_effects
    # the single stall is the margins study's probe (its own row), not a brick's effect
    probes = ("single_stall_s", "single_stall_at_s")
    fields = [f.name for f in dataclasses.fields(Brick) if f.name != "sources" and f.name not in probes]
    assert sorted(b.sources) == sorted(fields)                  # every value says where it comes from
    off = [f for f in fields if f != "gyro_mode_timeout" and getattr(b, f) == getattr(Brick(), f)]
    assert off == []                                           # every effect on (the timeout is a fault)
    assert b.single_stall_s == 0
    run = run_firmware(dataclasses.replace(sc, duration_s=0.3))
    assert run.completed or run.stop_reason == "overruns"
    assert run.duty_events and run.d_origin_m[0] == 0.0        # the firmware counts d from th1 = 0
