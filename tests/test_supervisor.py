"""The guard that outlives the controller (tipbot_fw.supervisor), in real processes against a
fake EV3: whatever ends or freezes the controller, every motor reads duty 0 and command stop
within 50 ms, and the log reads back."""
import json
import os
import signal
import time

import pytest

import faults
from conftest import PHYSICAL_GAINS
from tipbot_fw import config
from tipbot_fw.guard import heartbeat, safety
from tipbot_fw.cues import STOP_WORDS
from tipbot_fw.io.lights_speaker import COLOR_NAMES, STATES, stop_state
from tipbot_fw.supervisor import MotorStopper, Watch, _past_hold
from tipbot_fw import vocabulary

pytestmark = pytest.mark.slow   # real processes or long studies: not in make test-fast

LIMIT_S = 0.050
HOLD_S = config.defaults()['limits']['max_stall_s']


@pytest.fixture
def robot(tmp_path):
    cfg = tmp_path / 'cfg.json'
    cfg.write_text(json.dumps(faults.QUICK))
    made = []

    def make(**kw):
        r = faults.Robot(str(tmp_path / 'sys'), PHYSICAL_GAINS, str(cfg), str(tmp_path / 'run.log'), **kw)
        made.append(r)
        return r
    yield make
    for r in made:
        r.close()


@pytest.mark.parametrize('fault, code, reason', [
    ('kill-controller', safety.EXIT_CONTROLLER_DIED, None),
    ('kill-supervisor', None, 'supervisor_gone'),
    ('stop-controller', safety.EXIT_WATCHDOG, 'watchdog'),
    ('SIGQUIT', 143, 'signal'),
])
def test_every_motor_stops_within_50_ms_of_its_moment_and_the_log_reads_back(robot, fault, code, reason):
    # the moment: at once for a controller that ended, limits.max_stall_s after a freeze (its
    # held duties are a delayed law the robot rides out that long; the test's duties are far
    # from the saturation)
    r = robot()
    assert r.wait_driving(), r.finish()
    t = faults.inject(r, fault)
    status, out, err = r.finish()
    moment_s = HOLD_S if fault == 'stop-controller' else 0.0
    assert t is not None and moment_s <= t < moment_s + LIMIT_S, (t, err)
    if code is not None:
        assert status == code, err
    header, rows = r.log()
    assert len(rows) > 10
    if reason is None:      # SIGKILL: no end record, the rows written so far
        assert 'incomplete' in header and 'stop_reason' not in header
        assert 'killed by SIGKILL: motors stopped here' in err
    else:
        assert header['stop_reason'] == reason and 'incomplete' not in header, err
    assert 'Traceback' not in err
    # the brick shows why, the controller's death by its supervisor (which loads the cues only then)
    shown = reason or 'controller_died'
    left, right, _, _ = STATES[stop_state(shown)]
    assert r.fake.lights() == {'left': COLOR_NAMES[left], 'right': COLOR_NAMES[right]}
    assert 'tipbot: {} (exit {})'.format(STOP_WORDS[shown], header.get('exit_code', status)) in out


def test_the_tree_the_environment_names_is_the_supervisors_too(robot):
    # the loopback brick (make sim-brick) names its fake EV3 by TIPBOT_SYSFS_ROOT, no --sysfs-root
    r = robot(root_by_env=True)
    assert r.wait_driving(), r.finish()
    t = faults.inject(r, 'kill-controller')
    status, out, err = r.finish()
    assert t is not None and t < LIMIT_S and status == safety.EXIT_CONTROLLER_DIED, err
    assert 'no tacho motor found' not in err


def test_the_supervisor_reads_the_configuration_the_controller_runs_with(robot, tmp_path):
    # the launcher passes the deployed --config first; an owner's ./tipbot --config mine.json comes
    # after it, and the controller's argparse takes the last: so must the supervisor (its hold)
    deployed = dict(faults.QUICK, limits={'max_stall_s': 0.5})
    (tmp_path / 'cfg.json').write_text(json.dumps(deployed))
    mine = tmp_path / 'mine.json'
    mine.write_text(json.dumps(dict(faults.QUICK, limits={'max_stall_s': 0.05})))
    r = robot(extra=['--config', str(mine)])
    assert r.wait_driving(), r.finish()
    t = faults.inject(r, 'stop-controller')
    status, out, err = r.finish()
    assert t is not None and 0.05 <= t < 0.05 + LIMIT_S, (t, err)
    assert status == safety.EXIT_WATCHDOG and 'limits.max_stall_s = 0.05 s' in err, err


def test_a_continued_controller_cannot_restart_the_motors(robot):
    r = robot()
    assert r.wait_driving()
    pid = r.controller_pid()
    os.kill(pid, signal.SIGSTOP)
    assert r.time_to_stop() < HOLD_S + LIMIT_S
    try:
        os.kill(pid, signal.SIGCONT)    # the supervisor continues it too, to have it write its log
    except ProcessLookupError:
        pass
    seen = set()
    while r.proc.poll() is None:
        seen.update(r.commands())
    status, out, err = r.finish()
    assert seen <= {'stop'} and status == safety.EXIT_WATCHDOG and r.stopped()
    assert 'missed its heartbeat for' in err and r.log()[0]['stop_reason'] == 'watchdog'


def test_a_signal_before_the_handlers_and_the_devices_is_not_a_traceback(robot):
    # SIGINT to the whole process group the moment the supervisor exists (Ctrl-C at the start)
    r = robot()
    time.sleep(0.15)
    os.killpg(r.proc.pid, signal.SIGINT)
    status, out, err = r.finish()
    assert status in (130, 2 + 128) and 'Traceback' not in err, err
    assert all(c in ('', 'stop') for c in r.commands())


def test_the_watch_sleeps_from_the_calibration_to_the_first_tick(tmp_path):
    # the set-up in between (the core, the start cue, the loop's gc.collect) outlasts the stall
    # timeout on the brick; no motor is driven then
    import fw_support as S
    from tipbot_fw.io.clock import VirtualClock
    from tipbot_fw.cues import OwnerCues
    from tipbot_fw.io.devices import MemoryDevices
    from tipbot_fw.session import run_session

    fd, page, words = heartbeat.create_page()
    hbt = heartbeat.Heartbeat(words, os.getppid(), page)
    seen = {'reads': [], 'let_go': None}
    dev = MemoryDevices(source=lambda: seen['reads'].append((dev.write_calls, words[heartbeat.STATE]))
                        or ((0, 0, 0, 0), (0, 0)))

    class Cues(OwnerCues):
        def let_go(self):
            seen['let_go'] = words[heartbeat.STATE]

    code, _ = run_session(dev, S.load(), S.fw_config(), VirtualClock(), duration_s=0.05, say=lambda m: None,
                          cues=Cues(streams=()), heartbeat=hbt)
    assert code == 0
    calibration = [state for writes, state in seen['reads'] if writes == 0]
    ticks = [state for writes, state in seen['reads'] if writes > 0]
    assert set(calibration) == {heartbeat.ARMED} and seen['let_go'] == heartbeat.IDLE
    assert ticks and set(ticks) == {heartbeat.ARMED} and words[heartbeat.STATE] == heartbeat.IDLE


def test_the_watch_sees_a_stall_only_while_armed():
    fd, page, words = heartbeat.create_page()
    r, w = os.pipe()
    t = [0.0]
    watch = Watch(words, r, timeout_s=0.025, clock=lambda: t[0])
    assert watch.poll(0) is None
    t[0] = 1.0                                  # idle: a long pause is no stall
    assert watch.poll(0) is None
    words[heartbeat.STATE] = heartbeat.ARMED
    assert watch.poll(0) is None                # armed now: the timer starts here
    t[0] = 1.02
    words[heartbeat.BEAT] = 7
    assert watch.poll(0) is None
    t[0] = 1.04
    assert watch.poll(0) is None
    t[0] = 1.05
    kind, stood = watch.poll(0)
    assert kind == 'stalled' and stood == pytest.approx(0.03)
    os.close(w)
    assert watch.poll(0) == ('ended', 0.0)


def test_the_stopper_finds_the_configured_ports_and_stops_them(fake):
    for port in ('outA', 'outD'):
        for name, value in (('duty_cycle_sp', b'-55\n'), ('command', b'run-direct\n')):
            with open(fake.attribute_path(port, name), 'wb') as f:
                f.write(value)
    s = MotorStopper(fake.sysfs_root, ['outA', 'outB', 'outD'])
    assert s.stop() == []
    states = fake.poll()
    assert all(states[p].duty == 0 and not states[p].running and states[p].command == 'stop' for p in ('outA', 'outD'))
    assert states['outC'].command == ''        # not configured: untouched
    assert MotorStopper(fake.sysfs_root, ['outA', 'in9']).stop() == ['port in9: no tacho motor found']


@pytest.mark.parametrize('stall_s', [0.04, 0.08])
def test_a_controller_frozen_for_less_than_its_hold_keeps_its_motors_and_catches_up(robot, stall_s):
    # SIGSTOP for 40 or 80 ms, then SIGCONT: the H-bridges hold the last duties all along (no
    # stop is ever written), and the controller, back, predicts through the periods it missed
    # (their count in the late tick's flags) and goes on to its duration
    r = robot(extra=('--duration', '2.5'))
    assert r.wait_driving(), r.finish()
    pid = r.controller_pid()
    os.kill(pid, signal.SIGSTOP)
    t_end = time.monotonic() + stall_s
    seen = set()
    while time.monotonic() < t_end:
        seen.update(r.commands())
    os.kill(pid, signal.SIGCONT)
    for _ in range(50):
        seen.update(r.commands())
        time.sleep(0.002)
    status, out, err = r.finish()
    assert seen == {'run-direct'} and status == 0, err
    # the start says which scheduling it got (the test's config asks for none)
    assert 'tipbot: scheduling: normal (no real-time priority asked for' in out + err
    header, rows = r.log()
    assert header['stop_reason'] == 'completed'
    flags = rows[:, [c['name'] for c in header['columns']].index('flags')].astype(int)
    skipped = flags >> vocabulary.SKIP_SHIFT
    # one hold of about stall_s / 5 ms periods (the wall clock's scheduling adds a little)
    assert stall_s / 0.005 - 2 <= skipped.max() <= stall_s / 0.005 + 6, skipped.max()
    assert header['loop']['skipped_periods'] >= skipped.max()


class _Held(object):
    def __init__(self, duties):
        self.duties = duties

    def held_duties(self):
        return self.duties


def test_a_frozen_controller_loses_its_motors_past_its_hold_or_at_once_when_a_duty_is_at_its_saturation():
    assert _past_hold(0.03, 0.15, _Held([10, -20, 5, 0]), 95) is None
    assert 'limits.max_stall_s = 0.15 s' in _past_hold(0.16, 0.15, _Held([10, -20, 5, 0]), 95)
    # at the rail the controller published (u_max_v at this battery), or the driver's 100 %
    assert 'saturation (95 %)' in _past_hold(0.03, 0.15, _Held([95, -20, 5, 0]), 95)
    assert _past_hold(0.03, 0.15, _Held([95, -20, 5, 0]), 0) is None
    assert 'saturation (100 %)' in _past_hold(0.03, 0.15, _Held([0, -100, 5, 0]), 0)


def test_the_stopper_reads_the_held_duties_from_the_motors(tmp_path):
    from hostsim.world.fake_ev3 import FakeEV3
    with FakeEV3(str(tmp_path / 'sys')) as fake:
        stopper = MotorStopper(fake.sysfs_root, faults.PORTS)
        for port, duty in zip(faults.PORTS, ('37', '-100', '0', '5')):
            with open(fake.attribute_path(port, 'duty_cycle_sp'), 'w') as f:
                f.write(duty + '\n')
        assert stopper.held_duties() == [37, -100, 0, 5]
        assert stopper.stop() == [] and stopper.held_duties() == [0, 0, 0, 0]


def test_a_sigkill_of_the_whole_process_group_stops_every_motor_at_once(robot):
    # supervisor and controller killed together: the guard, in a session of its own, sees the
    # controller's end
    r = robot()
    assert r.wait_driving(), r.finish()
    t = faults.inject(r, 'kill-group')
    status, out, err = r.finish()
    assert t is not None and t < LIMIT_S, (t, err)
    assert status == -signal.SIGKILL and len(r.log()[1]) > 10
    assert 'Traceback' not in err


@pytest.mark.parametrize('fault', ['stop-group', 'stop-both'])
def test_a_sigstop_of_both_processes_stops_every_motor_past_the_hold(robot, fault):
    # both frozen for 0.5 s (the group at once, or one after the other): the guard applies the
    # supervisor's hold and stops the motors; continued, the controller ends for the stall
    r = robot()
    assert r.wait_driving(), r.finish()
    sup, ctl = r.proc.pid, r.controller_pid()
    t = faults.inject(r, fault)
    time.sleep(max(0.0, 0.5 - (t or 0.0)))
    for pid in (sup, ctl):
        os.kill(pid, signal.SIGCONT)
    status, out, err = r.finish()
    assert t is not None and HOLD_S <= t < HOLD_S + LIMIT_S, (t, err)
    assert status == safety.EXIT_WATCHDOG and r.stopped(), err
    assert 'tipbot: guard: the controller and the supervisor stood still' in err
    assert r.log()[0]['stop_reason'] == 'watchdog' and 'Traceback' not in err
