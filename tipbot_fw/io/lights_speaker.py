"""The brick's status lights and speaker: a light pair and a melody per state (tipbot_fw.cues
says when to show which).

Lights: the EV3's two status lights (left, right), each a red and a green LED in sysfs, named
as python-ev3dev2 2.1.0 names them (ev3dev2/_platform/ev3.py: ``led0:red:brick-status``, ...);
amber is red and green together (ev3dev2's LED_COLORS). They are written directly, ``b"255\\n"``
through a descriptor opened once, as tipbot_fw.io.ev3dev writes duties: ev3dev2's Leds would do the
same work with more Python per write, and writes without a newline, which a shorter value over a
longer one cannot be told from on the fake EV3.

Tones: ev3dev-stretch makes the EV3's speaker a Linux input device
(``/dev/input/by-path/platform-sound-event``). Writing one ``struct input_event`` (EV_SND,
SND_TONE, the frequency in Hz) starts a tone, frequency 0 stops it: one write(2) each, no
process (about 7,300 ARMv5 instructions on the virtual brick). ev3dev2's Sound.tone and
Sound.beep run ``/usr/bin/beep`` in a subprocess instead: a fork of this process (numpy loaded)
and an exec, whose Python side alone costs about 76,000 (docs/architecture.md), so they are
never used here. A note lasts
from its start event to the next event, so whoever plays a melody times it: blocking
(:meth:`BrickSignals.show`, outside the control loop) or tick by tick in the loop's slack
(tipbot_fw.cues.LoopCues, one write per call).

A light or speaker that is missing or fails is noted once (``problems``) and left alone: the
lights are never worth a failed start or a stopped run. Python 3.5, standard library only.
"""
import os
import struct
import time

# (red, green) of one status light, as ev3dev2's LED_COLORS (on = max_brightness)
OFF, GREEN, AMBER, RED = (0, 0), (0, 1), (1, 1), (1, 0)
COLOR_NAMES = {OFF: 'off', GREEN: 'green', AMBER: 'amber', RED: 'red'}

# The four LEDs in write order: (light, color, sysfs name under leds/).
LEDS = (('left', 'red', 'led0:red:brick-status'), ('left', 'green', 'led0:green:brick-status'),
        ('right', 'red', 'led1:red:brick-status'), ('right', 'green', 'led1:green:brick-status'))

# Every state: (left light, right light, melody as (Hz, seconds) notes, 0 Hz a rest), what it
# means. Left says the phase (amber: starting, green: running or done, red: stopped by a fault,
# off: stopped before running or by the owner), right the detail; rising melodies are good
# news, falling ones a stop. README has the table for owners ("What the brick shows").
STATES = {
    'hold': (AMBER, AMBER, ((440, 0.10), (0, 0.10), (440, 0.10)), 'hold still: calibrating the gyro'),
    'let_go': (AMBER, GREEN, ((523, 0.08), (659, 0.08), (784, 0.12)), 'let go now'),
    'balancing': (GREEN, GREEN, ((1047, 0.08),), 'balancing'),
    'battery_warning': (GREEN, AMBER, ((880, 0.06), (0, 0.06), (880, 0.06), (0, 0.06), (880, 0.06)),
                        'balancing, battery low'),
    'completed': (GREEN, OFF, ((784, 0.10), (659, 0.10), (523, 0.15)), 'done: ran its duration'),
    'fall': (RED, GREEN, ((392, 0.15), (262, 0.15), (196, 0.40)), 'stopped: fell'),
    'joint_limit': (RED, AMBER, ((330, 0.15), (0, 0.05), (330, 0.15), (262, 0.30)), 'stopped: joint limit'),
    'device_failure': (RED, OFF, ((220, 0.10), (0, 0.10), (220, 0.10), (0, 0.10), (220, 0.10)),
                       'stopped: a sensor or motor failed'),
    'overruns': (GREEN, RED, ((659, 0.05), (0, 0.05)) * 3 + ((659, 0.05),), 'stopped: ticks late'),
    'signal': (OFF, AMBER, ((523, 0.10), (392, 0.20)), 'stopped by a signal (Ctrl-C, SIGTERM, hang-up, ...)'),
    'low_battery': (AMBER, RED, ((330, 0.30), (262, 0.50)), 'not started: battery low'),
    'calibration': (OFF, RED, ((440, 0.10), (330, 0.30)), 'not started: moved during calibration'),
    'devices': (AMBER, OFF, ((196, 0.60),), 'not started: devices missing'),
    'error': (RED, RED, ((196, 0.20), (0, 0.10), (196, 0.20), (0, 0.10), (196, 0.40)),
              'stopped: an error (a bug, a crash, a stall)'),
}

# tipbot_fw.guard.safety's stop reasons -> states; any other reason shows 'error'. An implausible
# battery reading is a failed read (exit 5, as a sensor's); a motor held at its saturation is a
# robot that fell or is lost (exit 6, as a fall). The supervisor's stops (a stalled
# controller, 'watchdog'; one that died, 'controller_died', shown by the supervisor itself) and
# a lost supervisor are errors: the 16 light pairs hold no distinct one for them that is not
# 'all off', and the screen's words tell them apart.
STOP_STATES = {'completed': 'completed', 'fall': 'fall', 'saturated': 'fall', 'joint_limit': 'joint_limit',
               'device_failure': 'device_failure', 'battery_implausible': 'device_failure',
               'overruns': 'overruns', 'low_battery': 'low_battery', 'calibration': 'calibration',
               'devices': 'devices', 'keyboard_interrupt': 'signal', 'sigterm': 'signal', 'signal': 'signal'}


def stop_state(reason):
    return STOP_STATES.get(reason, 'error')


# linux/input-event-codes.h
EV_SND = 0x12
SND_TONE = 0x02
# struct input_event in the machine's own layout: struct timeval (two C longs), u16 type, u16
# code, s32 value; 16 bytes on the brick's 32-bit ARM (24 on a 64-bit host, for the fake EV3).
INPUT_EVENT = struct.Struct('@llHHi')
SYSFS_ROOT = '/sys/class'
SOUND_DEVICE = '/dev/input/by-path/platform-sound-event'
# Where a sysfs tree other than the real one (the fake EV3) keeps the sound device.
FAKE_SOUND_DEVICE = 'input-by-path/platform-sound-event'


def sound_device(sysfs_root):
    """The speaker's input device for this sysfs root."""
    if os.path.normpath(sysfs_root) == SYSFS_ROOT:
        return SOUND_DEVICE
    return os.path.join(sysfs_root, FAKE_SOUND_DEVICE)


def melody_plan(melody, t=0.0):
    """[(t_s, 'tone', Hz)] of a melody starting at t, ending with silence."""
    plan = []
    for hz, seconds in melody:
        plan.append((t, 'tone', hz))
        t += seconds
    plan.append((t, 'tone', 0))
    return plan


class BrickSignals(object):
    """The status lights and the speaker of the brick whose sysfs tree is at sysfs_root.

    ``problems``: one line per light or speaker that could not be opened or written (then left
    alone). ``sleep`` and ``now`` time the notes of show(). ``io``: open/write/pwrite/close with
    the API of :mod:`os` (as tipbot_fw.io.ev3dev takes one: a simulation times each write).
    """

    def __init__(self, sysfs_root=SYSFS_ROOT, sound_path=None, sleep=time.sleep, now=time.monotonic, io=os):
        self.sleep = sleep
        self.now = now
        self.io = io
        self.problems = []
        self.led_fds = []
        self.on = []
        self.shown = []
        for light, color, name in LEDS:
            path = os.path.join(sysfs_root, 'leds', name)
            fd = self._open(os.path.join(path, 'brightness'), os.O_WRONLY, 'light')
            if fd >= 0:
                self._no_trigger(path)
            self.led_fds.append(fd)
            self.on.append(self._max_brightness(path))
            self.shown.append(None)     # unknown until written
        self.sound_path = sound_path or sound_device(sysfs_root)
        self.tone_fd = self._open(self.sound_path, os.O_WRONLY | os.O_APPEND, 'speaker')
        self.tone_hz = 0

    def _open(self, path, flags, what):
        try:
            return self.io.open(path, flags)
        except OSError as e:
            self.problems.append('{}: cannot open {}: {}'.format(what, path, e.strerror or e))
            return -1

    def _no_trigger(self, path):
        """A kernel trigger (brickman's heartbeat or timer) would keep blinking over what is
        written: turn it off (a write of 0 to brightness would too, but not one of 255)."""
        try:
            fd = self.io.open(os.path.join(path, 'trigger'), os.O_WRONLY)
            try:
                self.io.write(fd, b'none\n')
            finally:
                self.io.close(fd)
        except OSError as e:
            self.problems.append('light: cannot turn off the trigger of {}: {}'.format(path, e.strerror or e))

    @staticmethod
    def _max_brightness(path):
        try:
            with open(os.path.join(path, 'max_brightness')) as f:
                return int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            return 255      # what ev3dev gives its LEDs

    def plan(self, state):
        """[(t_s, target, value)] that shows `state` from t = 0: first the LEDs whose value
        changes (target: LED index, value: brightness), then the melody (target 'tone')."""
        left, right, melody, _ = STATES[state]
        wanted = [left[0], left[1], right[0], right[1]]
        plan = [(0.0, i, on * self.on[i]) for i, on in enumerate(wanted)
                if self.led_fds[i] >= 0 and self.shown[i] != on * self.on[i]]
        if self.tone_fd >= 0:
            plan += melody_plan(melody)
        return plan

    def apply(self, target, value):
        """One write: LED `target` (index) to brightness `value`, or ('tone') a tone of `value`
        Hz (0: silence). Never raises: a failing device is noted and not written again."""
        if target == 'tone':
            if self.tone_fd < 0:
                return
            t = self.now()
            try:
                self.io.write(self.tone_fd, INPUT_EVENT.pack(int(t), int((t % 1.0) * 1e6), EV_SND, SND_TONE, value))
                self.tone_hz = value
            except OSError as e:
                self.problems.append('speaker: writing {} failed: {}'.format(self.sound_path, e))
                self.tone_fd = self._close(self.tone_fd)
            return
        fd = self.led_fds[target]
        if fd < 0:
            return
        try:
            self.io.pwrite(fd, b'%d\n' % value, 0)
            self.shown[target] = value
        except OSError as e:
            self.problems.append('light: writing {} failed: {}'.format(LEDS[target][2], e))
            self.led_fds[target] = self._close(fd)

    def show(self, state):
        """Show `state` now and play its melody to the end (blocking: outside the loop only)."""
        t0 = self.now()
        for t, target, value in self.plan(state):
            wait = t0 + t - self.now()
            if wait > 0:
                self.sleep(wait)
            self.apply(target, value)

    def silence(self):
        """Stop a tone still playing (a melody cut short: the loop ended before its last note)."""
        if self.tone_hz:
            self.apply('tone', 0)

    def _close(self, fd):
        try:
            self.io.close(fd)
        except OSError:
            pass
        return -1

    def close(self):
        """Stop any tone and close the descriptors (the lights keep their state: a stopped
        robot shows why until the next run)."""
        self.silence()
        for i, fd in enumerate(self.led_fds):
            if fd >= 0:
                self.led_fds[i] = self._close(fd)
        if self.tone_fd >= 0:
            self.tone_fd = self._close(self.tone_fd)
