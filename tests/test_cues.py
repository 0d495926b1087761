"""What the robot shows its owner (tipbot_fw.cues, tipbot_fw.io.lights_speaker), read back from the fake
EV3's files: every state's lights, melody and words, played outside the control tick."""
import os
import signal

import pytest

import fw_support as S
from hostsim.world.fake_ev3 import FakeEV3
from tipbot_fw import cli
from tipbot_fw.guard import safety
from tipbot_fw.calibration import sample_counts
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cues import BALANCING_AFTER_S, STOP_WORDS, LoopCues, OwnerCues
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.io.lights_speaker import COLOR_NAMES, LEDS, STATES, BrickSignals, melody_plan, stop_state
from tipbot_fw.loop import LoopStats
from tipbot_fw.session import run_session
from conftest import PHYSICAL_GAINS


class Clock(object):
    """now() and sleep() for BrickSignals: time moves only when it sleeps."""

    def __init__(self):
        self.t = 100.0

    def now(self):
        return self.t

    def sleep(self, s):
        self.t += s


class Lines(object):
    def __init__(self):
        self.lines = []

    def write(self, text):
        self.lines.append(text.rstrip('\n'))

    def flush(self):
        pass


def colors(state):
    left, right, _, _ = STATES[state]
    return {'left': COLOR_NAMES[left], 'right': COLOR_NAMES[right]}


def notes(state):
    return [hz for _, _, hz in melody_plan(STATES[state][2])]


@pytest.fixture
def ev3(tmp_path):
    f = FakeEV3(str(tmp_path / 'sys'))
    yield f
    f.close()


def quiet_brick(fake):
    """The fake's lights and speaker, melodies played without waiting."""
    return BrickSignals(fake.sysfs_root, sleep=lambda s: None)


def test_every_state_has_its_own_lights_and_melody():
    lights = [(left, right) for left, right, _, _ in STATES.values()]
    melodies = [melody for _, _, melody, _ in STATES.values()]
    assert len(set(lights)) == len(STATES) and len(set(melodies)) == len(STATES)
    for reason in ('fall', 'joint_limit', 'low_battery', 'device_failure', 'overruns', 'sigterm',
                   'keyboard_interrupt', 'calibration', 'devices', 'completed', 'signal', 'battery_implausible'):
        assert stop_state(reason) in STATES and reason in STOP_WORDS
    assert stop_state('exception') == stop_state('a reason of a later version') == 'error'
    # every stop reason the firmware and its supervisor give has its words on the screen
    for reason in ('watchdog', 'supervisor_gone', 'controller_died', 'exception'):
        assert stop_state(reason) == 'error' and reason in STOP_WORDS
    assert stop_state('battery_implausible') == 'device_failure'
    assert stop_state('signal') == stop_state('sigterm') == stop_state('keyboard_interrupt') == 'signal'


def test_the_lights_are_the_ones_python_ev3dev2_drives():
    from ev3dev2._platform import ev3
    assert {(side, color): name for side, color, name in LEDS} == {
        tuple(k.split('_')[::-1]): v for k, v in ev3.LEDS.items()}


@pytest.mark.parametrize('state', sorted(STATES))
def test_each_state_shows_its_lights_and_plays_its_melody_on_the_fake_ev3(ev3, state):
    clock = Clock()
    brick = BrickSignals(ev3.sysfs_root, sleep=clock.sleep, now=clock.now)
    assert brick.problems == []
    brick.show(state)
    assert ev3.lights() == colors(state)
    heard = ev3.tones()
    assert [hz for _, hz in heard] == notes(state)
    # each note lasts as long as the melody says (the writes carry the writer's clock)
    durations = [b[0] - a[0] for a, b in zip(heard, heard[1:])]
    assert durations == pytest.approx([s for _, s in STATES[state][2]], abs=2e-6)
    brick.close()


def test_the_lights_trigger_is_turned_off_so_that_a_color_stays(ev3):
    brick = quiet_brick(ev3)
    for _, _, name in LEDS:
        with open(os.path.join(ev3.sysfs_root, 'leds', name, 'trigger')) as f:
            assert f.readline().strip() == 'none'
    brick.close()


def test_a_brick_without_lights_or_speaker_is_told_and_left_alone(tmp_path):
    brick = BrickSignals(str(tmp_path / 'nothing'), sleep=lambda s: None)
    assert len(brick.problems) == 5 and all('cannot open' in p for p in brick.problems)
    brick.show('fall')          # nothing to write to: no error
    assert brick.plan('fall') == []
    brick.close()


def test_a_failing_light_is_noted_once_and_not_written_again(ev3):
    brick = quiet_brick(ev3)
    fd = os.open(os.devnull, os.O_RDONLY)       # writes to it fail (EBADF)
    os.close(brick.led_fds[0])
    brick.led_fds[0] = fd
    brick.show('fall')
    brick.show('hold')
    assert len(brick.problems) == 1 and brick.problems[0].startswith('light: writing led0:red:brick-status failed')
    assert ev3.lights() == {'left': 'green', 'right': 'amber'}     # the others still show 'hold'
    brick.close()


# ------------------------------------------------------------------------------ in the loop
class Recorder(object):
    """A brick that notes at which tick (the LoopCues call) each write happens."""

    def __init__(self, brick):
        self.brick, self.k, self.writes = brick, None, []

    def plan(self, state):
        return self.brick.plan(state)

    def apply(self, target, value):
        self.writes.append((self.k, target, value))
        self.brick.apply(target, value)


def drive(task, ticks):
    """Call a side task as tipbot_fw.loop does; -> the ticks it was called at."""
    called, due = [], 1
    for k in range(1, ticks):
        if k >= due:
            called.append(k)
            task.brick.k = k
            due = task(k)
            assert due > k
    return called


def test_the_loop_plays_the_let_go_melody_on_and_one_write_per_tick_at_most(ev3):
    brick = quiet_brick(ev3)
    cues = OwnerCues(streams=(), brick=brick)
    cues.let_go()       # its lights and first note now, the rest queued
    assert ev3.lights() == colors('let_go') and [hz for _, hz in ev3.tones()] == notes('let_go')[:1]
    stats = LoopStats()
    stats.battery_v = 8.0
    task = LoopCues(cues, 0.005, 200, stats, 7.0)
    task.brick = Recorder(brick)
    called = drive(task, 260)
    writes = task.brick.writes
    assert len({k for k, _, _ in writes}) == len(writes)        # one write per call
    # 659 Hz at 80 ms, 784 Hz at 160 ms, silence at 280 ms: ticks 16, 32, 56
    assert [(k, v) for k, t, v in writes if t == 'tone'][:3] == [(16, 659), (32, 784), (56, 0)]
    # balancing at 1 s: its lights (the left one changes, amber -> green) and its note
    balancing = [(k, t, v) for k, t, v in writes if k >= 200]
    assert balancing[0][0] == 200 and [v for _, t, v in balancing if t == 'tone'] == notes('balancing')
    assert ev3.lights() == colors('balancing')
    assert len(called) < 20        # called only when something is due


def test_a_low_battery_while_balancing_is_shown_and_said_once(ev3):
    brick = quiet_brick(ev3)
    words = Lines()
    cues = OwnerCues(streams=[words], brick=brick)
    stats = LoopStats()
    stats.battery_v = 8.0
    task = LoopCues(cues, 0.005, 200, stats, 7.0)
    drive(task, 300)
    assert ev3.lights() == colors('balancing')
    stats.battery_v = 6.9
    due = 400
    for k in range(400, 700):
        if k >= due:
            due = task(k)
    assert ev3.lights() == colors('battery_warning')
    assert [hz for _, hz in ev3.tones()][-len(notes('battery_warning')):] == notes('battery_warning')
    assert words.lines == ['tipbot: BATTERY LOW: 6.90 V (limits.warn_battery_v 7.0 V): charge it soon']


# ------------------------------------------------------------------------------ whole runs
def run(tmp_path, ev3, dev, clock=None, duration_s=0.3, config=None):
    words = Lines()
    code, header = run_session(dev, S.load(), config or S.fw_config(), clock or VirtualClock(),
                               log_path=str(tmp_path / 'run.log'), duration_s=duration_s, say=lambda m: None,
                               cues=OwnerCues(streams=[words], brick=quiet_brick(ev3)))
    return code, header, words.lines


def _raise(e):
    raise e


def _stop(kind, dev, clock):
    """The action of a TickCounter that makes a run on dev and clock stop for `kind`."""
    if kind == 'fall':
        return lambda n: setattr(dev, 'gyro', (0, 100))
    if kind == 'joint_limit':
        return lambda n: setattr(dev, 'enc', (0, 0, 0, 5 * n))
    if kind == 'device_failure':
        return lambda n: n == 20 and setattr(dev, 'source', lambda: _raise(OSError(19, 'No such device')))
    if kind == 'overruns':
        return lambda n: n >= 10 and clock.advance(0.02)
    if kind == 'battery_implausible':     # the loop reads it every 0.1 s here (run's config)
        return lambda n: n == 20 and setattr(dev, 'battery_v', 1e-6)
    if kind == 'sigterm':
        return lambda n: n == 20 and os.kill(os.getpid(), signal.SIGTERM)
    if kind == 'signal':
        return lambda n: n == 20 and os.kill(os.getpid(), signal.SIGUSR1)
    if kind == 'keyboard_interrupt':
        return lambda n: n == 20 and _raise(KeyboardInterrupt())
    if kind == 'exception':
        return lambda n: n == 20 and setattr(dev, 'enc', (None, 0, 0, 0))
    return lambda n: None


@pytest.mark.parametrize('reason, code', [('completed', 0), ('fall', 6), ('joint_limit', 6), ('device_failure', 5),
                                          ('battery_implausible', 5), ('overruns', 7), ('sigterm', 143),
                                          ('signal', 143), ('keyboard_interrupt', 130), ('exception', 1),
                                          ('low_battery', 4), ('calibration', 4)])
def test_each_stop_shows_its_lights_plays_its_melody_and_says_why(tmp_path, ev3, reason, code):
    dev = MemoryDevices(battery_v=6.0 if reason == 'low_battery' else 8.0)
    if reason == 'calibration':     # the gyro jolts while the robot should be held still
        settle, _ = sample_counts(S.fw_config()['gyro_calibration'], S.load().ts_s)
        reads = iter(range(10 ** 6))
        dev.source = lambda: ((0, 0, 0, 0), (0, 9 if next(reads) == settle + 3 else 0))
    clock = VirtualClock()
    clock.on_sleep = S.TickCounter(dev, _stop(reason, dev, clock))
    got, header, words = run(tmp_path, ev3, dev, clock, duration_s=0.8, config=S.fw_config(battery_period_s=0.1))
    assert (got, header['stop_reason']) == (code, reason)
    state = stop_state(reason)
    assert ev3.lights() == colors(state)
    assert [hz for _, hz in ev3.tones()][-len(notes(state)):] == notes(state)
    assert words[-1] == 'tipbot: {} (exit {})'.format(STOP_WORDS[reason], code)
    assert words[0].startswith('tipbot: HOLD' if reason != 'low_battery' else 'tipbot: NOT STARTED: battery low')


def test_a_run_shows_hold_let_go_balancing_and_done_in_turn(tmp_path, ev3):
    seen = []
    dev = MemoryDevices()
    dev.source = lambda: (seen.append(ev3.lights()) or ((0, 0, 0, 0), (0, 0)))
    settle, n = sample_counts(S.fw_config()['gyro_calibration'], S.load().ts_s)
    balancing = int(BALANCING_AFTER_S / S.load().ts_s)
    code, _, words = run(tmp_path, ev3, dev, duration_s=BALANCING_AFTER_S + 0.1)
    assert code == 0
    assert seen[0] == seen[settle + n - 1] == colors('hold')          # the whole calibration
    assert seen[settle + n] == colors('let_go')                       # the first tick
    assert seen[settle + n + balancing + 5] == colors('balancing')    # writes spread over a few ticks
    assert ev3.lights() == colors('completed')
    heard = [hz for _, hz in ev3.tones()]
    assert heard == notes('hold') + notes('let_go') + notes('balancing') + notes('completed')
    assert words == ['tipbot: HOLD the robot still and upright: calibrating the gyro (0.2 s)',
                     'tipbot: LET GO NOW: balancing', 'tipbot: DONE: ran its duration (exit 0)']


# ------------------------------------------------------------------------------ the command line
@pytest.fixture
def quick_config(tmp_path):
    return S.write_json(tmp_path / 'quick.json',
                        {'realtime_priority': 0, 'gyro_calibration': {'settle_s': 0.05, 'duration_s': 0.05}})


@pytest.mark.slow
def test_the_command_line_shows_the_brick_its_cues_unless_quiet(ev3, tmp_path, quick_config, capsys):
    argv = ['run', '--gains', PHYSICAL_GAINS, '--config', quick_config, '--duration', '0.3',
            '--log', str(tmp_path / 'run.log'), '--sysfs-root', ev3.sysfs_root]
    assert cli.main(argv) == 0
    out, err = capsys.readouterr()
    assert ev3.lights() == colors('completed')
    assert [hz for _, hz in ev3.tones()] == notes('hold') + notes('let_go') + notes('completed')
    assert 'tipbot: DONE: ran its duration (exit 0)\n' in out and 'DONE' not in err
    heard = len(ev3.tones())
    assert cli.main(argv + ['--quiet']) == 0
    out, err = capsys.readouterr()
    assert len(ev3.tones()) == heard and ev3.lights() == colors('completed')   # untouched
    assert out == '' and 'tipbot: LET GO NOW: balancing' in err


def test_missing_devices_are_shown_too(tmp_path, quick_config, capsys):
    ev3 = FakeEV3(str(tmp_path / 'sys'), motors={'outC': None})
    try:
        code = cli.main(['run', '--gains', PHYSICAL_GAINS, '--config', quick_config, '--log',
                         str(tmp_path / 'run.log'), '--sysfs-root', ev3.sysfs_root])
        assert code == safety.EXIT_DEVICES
        assert ev3.lights() == colors('devices')
        assert 'tipbot: NOT STARTED: devices missing (exit 3)' in capsys.readouterr().out
    finally:
        ev3.close()


def test_a_failing_cue_cannot_change_how_a_run_ends(tmp_path):
    class Broken(OwnerCues):
        def stopped(self, reason, code):
            raise RuntimeError('no screen')

    said = []
    code, header = run_session(MemoryDevices(), S.load(), S.fw_config(), VirtualClock(), log_path=str(tmp_path / 'r.log'),
                               duration_s=0.1, say=said.append, cues=Broken(streams=()))
    assert code == 0 and header['stop_reason'] == 'completed' and os.path.exists(str(tmp_path / 'r.log'))
    assert said[-1] == "could not show why it stopped: RuntimeError('no screen')"
