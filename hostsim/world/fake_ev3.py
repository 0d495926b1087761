"""A fake EV3 sysfs tree on disk, for python-ev3dev2 and tipbot_fw.io.ev3dev.Ev3Devices.

The tree has the ev3dev-stretch layout and attribute formats::

    ROOT/tacho-motor/motorN/    address (ev3-ports:outA), driver_name, position, duty_cycle_sp, ...
    ROOT/lego-sensor/sensor0/   address (ev3-ports:in2), driver_name (lego-ev3-gyro), mode, bin_data, ...
    ROOT/power_supply/lego-ev3-battery/voltage_now   (microvolts)
    ROOT/board-info/board0/uevent
    ROOT/leds/led0:red:brick-status/brightness, ...   (the status lights: tipbot_fw.io.lights_speaker.LEDS)
    ROOT/input-by-path/platform-sound-event         (the speaker's input device, a plain file here)

Clients point at ROOT (``ev3dev2.Device.DEVICE_ROOT_PATH = fake.sysfs_root`` or
``Ev3Devices(config, sysfs_root=fake.sysfs_root)``) and need no patching. The files on disk are
the truth, so the firmware may run in another process than the simulation that owns the fake.

Why the files behave like sysfs although they are regular files
----------------------------------------------------------------
On sysfs every read returns the current value and every write replaces the whole value. On a
regular file a shorter write over a longer value leaves the old tail behind (python-ev3dev2
writes with seek(0) + write on a handle opened 'r+', without a newline), and a reader racing a
writer may see half of each. So:

* Attributes the fake owns (position, bin_data, value<N>, voltage_now, state, ...) are written
  as fixed-size records, "value\\n" padded with spaces (bin_data: raw bytes padded with zeros),
  with ONE ``os.pwrite`` at offset 0. The file length never changes, so a reader never sees an
  empty or truncated file, and two records differ only in their first 12 bytes (the longest
  value, a 32-bit count, plus its newline; bin_data: 4 bytes), all within one page and one
  cache line. tests/test_ev3io.py checks across processes that no torn value is ever read.
  Readers strip whitespace (ev3dev2) or parse with ``int()`` (Ev3Devices), which ignores the
  padding.
* Attributes clients write (command, duty_cycle_sp, polarity, stop_action, mode, ...) are never
  rewritten by the fake after creation: rewriting would race with a client in another process
  and lose its write. Instead :meth:`FakeEV3.poll` parses what is there:
  - the first line: Ev3Devices writes ``b"%d\\n"`` / ``b"word\\n"``, so a short write after a long
    one still ends at its own newline (b"5\\n" over b"100\\n" reads b"5\\n0\\n");
  - for vocabulary attributes (command, polarity, stop_action, mode), the known value that
    prefixes that line, which also undoes ev3dev2's newline-less overwrites ("normal" over
    "inversed" reads "normaled" -> "normal"). No vocabulary value is a prefix of another, so the
    match is unique.
  - command files are write-only (mode 0220) as on sysfs, so ev3dev2 opens them with 'w'.
* Limits of this scheme (documented, not hidden): an INTEGER written by ev3dev2 (no newline)
  over a longer one is ambiguous ("5" over "100" reads "500"); read-backs of client-written
  attributes return the raw overlay (e.g. ev3dev2 reads "normaled"); only the last value
  written to an attribute between two polls is seen, so a ``reset`` followed by ``run-direct``
  before the next poll is lost (a repeated identical command IS seen when the file's mtime
  moves); ``position`` is read-only here (0444; real sysfs lets a client write it).

Counting and failure injection
------------------------------
:class:`CountingIO` has the ``open/pread/pwrite/write/close`` API of :mod:`os` (what Ev3Devices
and the lights and speaker of tipbot_fw.io.lights_speaker take as ``io``), counts calls per path and can make chosen calls raise ``OSError``; ``fake.io`` is one
bound to this tree. It is an in-process add-on only: the files remain the truth.
"""

import errno
import os
import shutil
import stat
import struct
import tempfile
from collections import Counter, namedtuple

from tipbot_fw.io import lights_speaker

#: Size of every fake-owned text record (value + "\n" + space padding) and of bin_data.
RECORD_BYTES = 32
#: The IR sensor's modes (ev3_uart_sensor_defs.c; ../shared/ev3-hardware.md).
IR_MODE_NAMES = ('IR-PROX', 'IR-SEEK', 'IR-REMOTE', 'IR-REM-A', 'IR-S-ALT', 'IR-CAL')
#: lego-sensor bin_data is a 32-byte binary attribute (LEGO_SENSOR_RAW_DATA_SIZE).
BIN_DATA_BYTES = 32

MOTOR_COMMANDS = ('run-forever', 'run-to-abs-pos', 'run-to-rel-pos', 'run-timed',
                  'run-direct', 'stop', 'reset')
STOP_ACTIONS = ('coast', 'brake', 'hold')
POLARITIES = ('normal', 'inversed')

#: (name, number of values, units) of the lego-ev3-gyro modes (ev3_uart_sensor_defs.c); all
#: s16 little-endian, 0 decimals.
GYRO_MODES = (
    ('GYRO-ANG', 1, 'deg'),
    ('GYRO-RATE', 1, 'd/s'),
    ('GYRO-FAS', 1, ''),
    ('GYRO-G&A', 2, ''),
    ('GYRO-CAL', 4, ''),
    ('TILT-RATE', 1, 'd/s'),
    ('TILT-ANG', 1, 'deg'),
)
_GYRO_MODE_INFO = {name: (n, units) for name, n, units in GYRO_MODES}
GYRO_MODE_NAMES = tuple(name for name, _, _ in GYRO_MODES)
#: Modes whose value0 is the angle: entering one restarts the angle from 0, as the sensor does.
_ANGLE_MODES = ('GYRO-ANG', 'GYRO-G&A')
#: After a mode switch the UART sensor keeps sending the previous mode's messages until it has
#: switched (tipbot_fw.io.ev3dev; ev3dev waits for new-mode data up to 50 ms per try): for this
#: long after the switch the fake keeps the previous mode's record in bin_data and value<N>.
GYRO_MODE_SWITCH_S = 0.05
#: A mode write waits for data in the new mode: 10 tries of 50 ms, then ETIMEDOUT
#: (sensors/ev3_uart_sensor_ld.c; ../shared/ev3-hardware.md).
GYRO_MODE_TRY_S = 0.05
GYRO_MODE_TRIES = 10

#: ev3dev's max_speed (tacho counts/s) per driver.
MAX_SPEED = {'lego-ev3-l-motor': 1050, 'lego-ev3-m-motor': 1560, 'lego-nxt-motor': 1020}
COUNT_PER_ROT = 360

DEFAULT_MOTORS = (('outA', 'lego-ev3-l-motor'), ('outB', 'lego-ev3-l-motor'),
                  ('outC', 'lego-ev3-l-motor'), ('outD', 'lego-ev3-m-motor'))
#: Motor ports in the firmware's role order (right wheel, left wheel, joint 2, joint 3).
DEFAULT_MOTOR_PORTS = tuple(port for port, _ in DEFAULT_MOTORS)

_S16_MIN, _S16_MAX = -32768, 32767
_DUTY_LIMIT = 100

_RO, _RW, _WO = 0o444, 0o664, 0o220

#: What :meth:`FakeEV3.poll` reports per motor port. ``duty`` is the duty actually applied
#: (percent, after sysfs polarity; 0 unless running run-direct).
MotorState = namedtuple('MotorState', 'duty running command duty_sp polarity stop_action')


def _first_line(raw):
    return raw.split(b'\n', 1)[0].strip().decode('ascii', 'replace')


def parse_choice(raw, choices):
    """The value of ``choices`` that prefixes the first line of ``raw`` (bytes), else None."""
    line = _first_line(raw)
    best = None
    for choice in choices:
        if line.startswith(choice) and (best is None or len(choice) > len(best)):
            best = choice
    return best


def _check_prefix_free(choices):
    for a in choices:
        for b in choices:
            if a != b and b.startswith(a):
                raise AssertionError('vocabulary %r: %r is a prefix of %r' % (choices, a, b))


for _vocab in (MOTOR_COMMANDS, STOP_ACTIONS, POLARITIES, GYRO_MODE_NAMES):
    _check_prefix_free(_vocab)


class FakeEV3Error(Exception):
    """Misuse of the fake itself (unknown port, value that does not fit its record)."""


class CountingIO(object):
    """``os``-compatible open/pread/pwrite/write/close that counts calls and can inject failures.

    ``reads``/``writes`` count pread and pwrite/write calls (failed ones too: they were attempted);
    ``by_path`` counts them per (op, path relative to ``root``); ``log`` lists
    (op, relpath, bytes written or bytes read). ``open_fds`` maps the fds still open to paths.
    """

    def __init__(self, root=None):
        self.root = root
        self.open_fds = {}
        self._failures = {}
        self.reset()

    def reset(self):
        """Zero the counters and the log (e.g. at the start of a tick)."""
        self.reads = 0
        self.writes = 0
        self.by_path = Counter()
        self.log = []

    def _rel(self, path):
        path = os.fspath(path)
        if self.root and path.startswith(self.root + os.sep):
            return path[len(self.root) + 1:]
        return path

    def fail(self, relpath, op='pread', err=errno.ENODEV):
        """Make every ``op`` ('pread', 'pwrite', 'write' or 'open') on ``relpath`` raise OSError(err)."""
        if op not in ('pread', 'pwrite', 'write', 'open'):
            raise ValueError('op must be pread, pwrite, write or open, not %r' % (op,))
        self._failures[(op, relpath)] = err

    def clear_failures(self):
        self._failures.clear()

    def _maybe_fail(self, op, rel):
        err = self._failures.get((op, rel))
        if err is not None:
            raise OSError(err, '%s (injected by CountingIO)' % os.strerror(err), rel)

    def open(self, path, flags, mode=0o777):
        rel = self._rel(path)
        self._maybe_fail('open', rel)
        fd = os.open(path, flags, mode)
        self.open_fds[fd] = rel
        return fd

    def pread(self, fd, n, offset):
        rel = self.open_fds.get(fd, '<fd %d>' % fd)
        self.reads += 1
        self.by_path[('pread', rel)] += 1
        self._maybe_fail('pread', rel)
        data = os.pread(fd, n, offset)
        self.log.append(('pread', rel, data))
        return data

    def pwrite(self, fd, data, offset):
        rel = self.open_fds.get(fd, '<fd %d>' % fd)
        self.writes += 1
        self.by_path[('pwrite', rel)] += 1
        self.log.append(('pwrite', rel, bytes(data)))
        self._maybe_fail('pwrite', rel)
        return os.pwrite(fd, data, offset)

    def write(self, fd, data):
        """write(2), for what has no offset (the speaker's input device: tipbot_fw.io.lights_speaker)."""
        rel = self.open_fds.get(fd, '<fd %d>' % fd)
        self.writes += 1
        self.by_path[('write', rel)] += 1
        self.log.append(('write', rel, bytes(data)))
        self._maybe_fail('write', rel)
        return os.write(fd, data)

    def close(self, fd):
        self.open_fds.pop(fd, None)
        os.close(fd)

    def writes_to(self, suffix):
        """The bytes written (in order) to paths ending with ``suffix``, from the log."""
        return [data for op, rel, data in self.log if op in ('pwrite', 'write') and rel.endswith(suffix)]


class _Attr(object):
    """One attribute file; ``fd`` is the fake's own read-write descriptor, opened before the
    file got its sysfs permissions (permissions are only checked at open)."""

    __slots__ = ('path', 'fd', 'size', 'last', 'sig')

    def __init__(self, path, fd, size, last):
        self.path = path
        self.fd = fd
        self.size = size
        self.last = last      # bytes last written by the fake, or last seen from a client
        self.sig = None       # (content, mtime_ns) of a command file, to see repeated commands


class _Device(object):
    def __init__(self, port, driver, path):
        self.port = port
        self.driver = driver
        self.path = path
        self.attrs = {}


class _Motor(_Device):
    def __init__(self, port, driver, path):
        _Device.__init__(self, port, driver, path)
        self.hw_counts = 0        # the encoder's own counter, before reset offset and polarity
        self.reset_offset = 0
        self.speed = 0
        self.running = False
        self.command = ''
        self.duty_sp = 0
        self.polarity = 'normal'
        self.stop_action = 'coast'
        self.duty = 0

    def sign(self):
        return -1 if self.polarity == 'inversed' else 1

    def state(self):
        return MotorState(self.duty, self.running, self.command, self.duty_sp, self.polarity,
                          self.stop_action)


class _Gyro(_Device):
    def __init__(self, port, driver, path):
        _Device.__init__(self, port, driver, path)
        self.mode = 'GYRO-ANG'     # the mode a freshly plugged gyro reports
        self.angle = 0             # the sensor's integrated angle, in its own frame
        self.angle_ref = 0         # angle when an angle mode was last entered
        self.rate = 0
        self.stale_until_s = None  # the previous mode's record stays until then (a mode switch)


class FakeEV3(object):
    """An ev3dev sysfs tree in a directory, driven by the simulation.

    ``motors`` overrides the default set {outA, outB, outC: lego-ev3-l-motor, outD:
    lego-ev3-m-motor}: ``{'outD': 'lego-ev3-l-motor'}`` puts a wrong motor on D, ``{'outC':
    None}`` unplugs C. ``gyro_port=None`` leaves out the gyro; ``gyro_driver`` can name another
    sensor. ``root_dir=None`` makes (and :meth:`close` removes) a temporary directory; a given
    ``root_dir`` must be empty or absent and is left in place.

    Time: a driver that passes the time to :meth:`poll` gets the gyro's mode switch delay
    (``gyro_mode_switch_s``: the previous mode's readings for that long after the switch);
    without it the switch is immediate. A driver that times the clients' accesses
    (hostsim.world.brick_timing) asks :meth:`write_cost` how long a write blocks:
    ``gyro_mode_write_s`` for a gyro mode write (the driver waits for data in the new mode),
    and with ``gyro_mode_timeout`` (an old sensor stuck in GYRO-G&A) every mode write blocks
    10 x 50 ms and fails with ETIMEDOUT.
    """

    def __init__(self, root_dir=None, battery_v=8.0, motors=None, gyro_port='in2',
                 gyro_driver='lego-ev3-gyro', gyro_mode_switch_s=GYRO_MODE_SWITCH_S, gyro_mode_write_s=0.0,
                 gyro_mode_timeout=False, ir_port=None):
        self._own_root = root_dir is None
        if root_dir is None:
            root_dir = tempfile.mkdtemp(prefix='fake-ev3-')
        else:
            os.makedirs(root_dir, exist_ok=True)
            if os.listdir(root_dir):
                raise FakeEV3Error('root_dir %s is not empty' % root_dir)
        self.sysfs_root = os.path.abspath(root_dir)
        self.io = CountingIO(self.sysfs_root)
        #: Client mistakes the real driver would reject with EINVAL (the value is not applied).
        self.errors = []
        self._fds = []
        self.gyro_mode_switch_s = gyro_mode_switch_s
        self.gyro_mode_write_s = gyro_mode_write_s
        self.gyro_mode_timeout = gyro_mode_timeout
        self.now_s = None          # the time of the latest poll(t_s), if the driver gives one

        spec = dict(DEFAULT_MOTORS)
        spec.update(motors or {})
        self._motors = {}
        index = 0
        for port, driver in sorted(spec.items()):
            if driver is None:
                continue
            path = os.path.join(self.sysfs_root, 'tacho-motor', 'motor%d' % index)
            index += 1
            self._motors[port] = self._make_motor(port, driver, path)
        self.motor_ports = tuple(sorted(self._motors))

        self._gyro = None
        if gyro_port is not None:
            path = os.path.join(self.sysfs_root, 'lego-sensor', 'sensor0')
            self._gyro = self._make_gyro(gyro_port, gyro_driver, path)
        self._ir = None
        if ir_port is not None:
            self._ir = self._make_ir(ir_port, os.path.join(self.sysfs_root, 'lego-sensor', 'sensor1'))
        self._make_battery(battery_v)
        self._make_board_info()
        self._make_lights()
        self._make_speaker()
        # relpath -> device, for poll_attribute
        self._by_relpath = {}
        for dev in list(self._motors.values()) + ([self._gyro] if self._gyro else []):
            for name, attr in dev.attrs.items():
                self._by_relpath[os.path.relpath(attr.path, self.sysfs_root)] = dev

    # ----------------------------------------------------------------- tree creation
    def _new_file(self, path, content, mode, size=None):
        """Create ``path`` holding ``content`` (str: a text record; bytes: as is, zero padded
        to ``size``) with sysfs-like permissions ``mode``; return its _Attr."""
        if isinstance(content, str):
            data = self._record(content, size or RECORD_BYTES)
        else:
            data = content.ljust(size or len(content), b'\0')
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        self._fds.append(fd)
        os.pwrite(fd, data, 0)
        os.fchmod(fd, mode)
        return _Attr(path, fd, len(data), data)

    @staticmethod
    def _record(text, size):
        data = text.encode('ascii') + b'\n'
        if len(data) > size:
            raise FakeEV3Error('value %r does not fit a %d-byte record' % (text, size))
        return data.ljust(size, b' ')

    def _add(self, dev, name, content, mode=_RO, size=None):
        if isinstance(content, str) and size is None:
            size = max(RECORD_BYTES, len(content) + 1)
        dev.attrs[name] = self._new_file(os.path.join(dev.path, name), content, mode, size)

    def _make_motor(self, port, driver, path):
        os.makedirs(path)
        m = _Motor(port, driver, path)
        add = self._add
        add(m, 'address', 'ev3-ports:' + port)
        add(m, 'driver_name', driver)
        add(m, 'commands', ' '.join(MOTOR_COMMANDS))
        add(m, 'command', b'', _WO)
        add(m, 'count_per_rot', str(COUNT_PER_ROT))
        add(m, 'max_speed', str(MAX_SPEED.get(driver, 1050)))
        add(m, 'position', '0')
        add(m, 'speed', '0')
        add(m, 'duty_cycle', '0')
        add(m, 'state', '')
        add(m, 'stop_actions', ' '.join(STOP_ACTIONS))
        add(m, 'duty_cycle_sp', '0', _RW)
        add(m, 'polarity', 'normal', _RW)
        add(m, 'stop_action', 'coast', _RW)
        # Present so that clients can set them; the fake does not simulate these run modes.
        for name in ('speed_sp', 'position_sp', 'time_sp', 'ramp_up_sp', 'ramp_down_sp'):
            add(m, name, '0', _RW)
        m.attrs['command'].sig = self._command_sig(m.attrs['command'])
        return m

    def _make_gyro(self, port, driver, path):
        os.makedirs(path)
        g = _Gyro(port, driver, path)
        add = self._add
        add(g, 'address', 'ev3-ports:' + port)
        add(g, 'driver_name', driver)
        add(g, 'modes', ' '.join(GYRO_MODE_NAMES))
        add(g, 'mode', g.mode, _RW)
        add(g, 'num_values', '1')
        add(g, 'decimals', '0')
        add(g, 'units', 'deg')
        add(g, 'bin_data_format', 's16')
        add(g, 'bin_data', b'', _RO, BIN_DATA_BYTES)
        for i in range(8):
            add(g, 'value%d' % i, '0')
        self._publish_gyro(g)
        return g

    def _make_ir(self, port, path):
        """The IR sensor (lego-ev3-ir): its modes, the mode a client writes, four values (in
        IR-REMOTE the four channels' button codes, which set_ir_buttons sets)."""
        os.makedirs(path)
        d = _Device(port, 'lego-ev3-ir', path)
        add = self._add
        add(d, 'address', 'ev3-ports:' + port)
        add(d, 'driver_name', 'lego-ev3-ir')
        add(d, 'modes', ' '.join(IR_MODE_NAMES))
        add(d, 'mode', IR_MODE_NAMES[0], _RW)
        for i in range(4):
            add(d, 'value%d' % i, '0')
        return d

    def set_ir_buttons(self, channel, code):
        """The button code (0-11) the IR sensor reads on remote channel 1-4."""
        self._put(self._ir.attrs['value%d' % (channel - 1)], str(int(code)))

    def ir_mode(self):
        """The IR sensor's mode as a client last wrote it."""
        return os.pread(self._ir.attrs['mode'].fd, 4096, 0).decode('ascii').split()[0]

    def _make_battery(self, battery_v):
        self._battery = _Device('battery', 'lego-ev3-battery',
                                os.path.join(self.sysfs_root, 'power_supply', 'lego-ev3-battery'))
        b = self._battery
        os.makedirs(b.path)
        add = self._add
        add(b, 'voltage_now', '0')
        add(b, 'current_now', '0')
        add(b, 'voltage_max_design', '9000000')
        add(b, 'voltage_min_design', '4800000')
        add(b, 'technology', 'Unknown')
        add(b, 'type', 'Battery')
        add(b, 'scope', 'System')
        add(b, 'uevent', 'POWER_SUPPLY_NAME=lego-ev3-battery', _RO)
        self.set_battery_v(battery_v)

    def _make_board_info(self):
        path = os.path.join(self.sysfs_root, 'board-info', 'board0')
        os.makedirs(path)
        text = ('BOARD_INFO_HW_REV=6\nBOARD_INFO_MODEL=LEGO MINDSTORMS EV3\n'
                'BOARD_INFO_ROM_REV=6\nBOARD_INFO_SERIAL_NUM=FAKE00000000\nBOARD_INFO_TYPE=main')
        fd = os.open(os.path.join(path, 'uevent'), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            os.write(fd, (text + '\n').encode('ascii'))
        finally:
            os.close(fd)

    def _make_lights(self):
        self._lights = []
        for _, _, name in lights_speaker.LEDS:
            led = _Device(name, 'leds-pwm', os.path.join(self.sysfs_root, 'leds', name))
            os.makedirs(led.path)
            self._add(led, 'brightness', '0', _RW)
            self._add(led, 'max_brightness', '255')
            self._add(led, 'trigger', '[none] timer heartbeat default-on', _RW)
            self._lights.append(led)

    def _make_speaker(self):
        """The speaker's input device: the firmware appends struct input_event records (one
        tone event each); kept whole, so a test hears every note and when it started."""
        path = lights_speaker.sound_device(self.sysfs_root)
        os.makedirs(os.path.dirname(path))
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o660)
        self._fds.append(fd)
        self._speaker_fd = fd

    # ----------------------------------------------------------------- fake-owned values
    def _put(self, attr, text):
        data = self._record(text, attr.size)
        if data != attr.last:
            os.pwrite(attr.fd, data, 0)
            attr.last = data

    def _put_bytes(self, attr, data):
        data = data.ljust(attr.size, b'\0')
        if data != attr.last:
            os.pwrite(attr.fd, data, 0)
            attr.last = data

    def _motor(self, port):
        try:
            return self._motors[port]
        except KeyError:
            raise FakeEV3Error('no motor on port %r (ports: %s)' % (port, ', '.join(self.motor_ports)))

    def _publish_position(self, m):
        self._put(m.attrs['position'], str(m.sign() * (m.hw_counts - m.reset_offset)))
        self._put(m.attrs['speed'], str(m.sign() * m.speed))

    def set_encoder_counts(self, port, counts, speed=None):
        """Set the encoder's own counter (integer counts, 360 per turn) and optionally its
        speed (counts/s). ``position`` then reads it minus the count at the last ``reset``
        command, negated if the client set polarity ``inversed`` (as the driver does)."""
        m = self._motor(port)
        m.hw_counts = int(counts)
        if speed is not None:
            m.speed = int(speed)
        self._publish_position(m)

    def set_readings(self, counts, gyro=None, battery_v=None, ports=DEFAULT_MOTOR_PORTS):
        """One call per simulation step: 4 encoder counts in role order (right, left, joint 2,
        joint 3 = ``ports``), optionally (angle_deg, rate_dps) and the battery voltage."""
        for port, c in zip(ports, counts):
            self.set_encoder_counts(port, c)
        if gyro is not None:
            self.set_gyro(gyro[0], gyro[1])
        if battery_v is not None:
            self.set_battery_v(battery_v)

    def set_gyro(self, angle_deg, rate_dps):
        """Set the gyro's integrated angle (deg, in the sensor's own frame) and rate (deg/s).

        Like the real sensor, the angle it reports restarts from 0 when a client switches into
        an angle mode (GYRO-ANG, GYRO-G&A), so value0 = angle_deg minus the angle at that
        switch. Values are clipped to s16 (the bin_data format)."""
        g = self._gyro
        if g is None:
            raise FakeEV3Error('this fake has no gyro')
        g.angle = int(angle_deg)
        g.rate = int(rate_dps)
        self._publish_gyro(g)

    def _gyro_values(self, g):
        angle = min(max(g.angle - g.angle_ref, _S16_MIN), _S16_MAX)
        rate = min(max(g.rate, _S16_MIN), _S16_MAX)
        return {
            'GYRO-ANG': (angle,), 'GYRO-RATE': (rate,), 'GYRO-FAS': (rate,),
            'GYRO-G&A': (angle, rate), 'GYRO-CAL': (0, 0, 0, 0),
            'TILT-RATE': (0,), 'TILT-ANG': (0,),
        }[g.mode]

    def _publish_gyro(self, g):
        if g.stale_until_s is not None:
            if self.now_s is not None and self.now_s < g.stale_until_s:
                return
            g.stale_until_s = None
        values = self._gyro_values(g)
        # bin_data first: it is what Ev3Devices reads, in one pwrite for both values.
        self._put_bytes(g.attrs['bin_data'], struct.pack('<%dh' % len(values), *values))
        for i in range(8):
            self._put(g.attrs['value%d' % i], str(values[i]) if i < len(values) else '0')

    def _publish_gyro_mode(self, g):
        n, units = _GYRO_MODE_INFO[g.mode]
        self._put(g.attrs['num_values'], str(n))
        self._put(g.attrs['units'], units)
        self._publish_gyro(g)

    def set_battery_v(self, volts):
        """Battery voltage in volts (written as integer microvolts, as the driver does)."""
        self._put(self._battery.attrs['voltage_now'], str(int(round(volts * 1e6))))

    # ----------------------------------------------------------------- client writes
    @staticmethod
    def _command_sig(attr):
        st = os.fstat(attr.fd)
        return (os.pread(attr.fd, 4096, 0), st.st_mtime_ns, st.st_size)

    def _read_client(self, attr):
        """The attribute's bytes if a client changed them since the last poll, else None."""
        raw = os.pread(attr.fd, 4096, 0)
        if raw == attr.last:
            return None
        attr.last = raw
        return raw

    def _error(self, where, name, raw, why):
        self.errors.append('%s %s: %s (wrote %r)' % (where, name, why, raw))

    def _choice(self, where, name, raw, choices):
        value = parse_choice(raw, choices)
        if value is None:
            self._error(where, name, raw, 'not one of %s' % ' '.join(choices))
        return value

    def _int(self, where, name, raw, limit=None):
        try:
            value = int(_first_line(raw))
        except ValueError:
            self._error(where, name, raw, 'not an integer')
            return None
        if limit is not None and not -limit <= value <= limit:
            self._error(where, name, raw, 'out of range [-%d, %d]' % (limit, limit))
            return None
        return value

    def _poll_motor(self, m):
        self._poll_command(m)
        self._poll_duty(m)
        where = 'port %s' % m.port
        attrs = m.attrs
        raw = self._read_client(attrs['polarity'])
        if raw is not None:
            value = self._choice(where, 'polarity', raw, POLARITIES)
            if value is not None:
                m.polarity = value
        raw = self._read_client(attrs['stop_action'])
        if raw is not None:
            value = self._choice(where, 'stop_action', raw, STOP_ACTIONS)
            if value is not None:
                m.stop_action = value
        for name in ('speed_sp', 'position_sp', 'time_sp', 'ramp_up_sp', 'ramp_down_sp'):
            raw = self._read_client(attrs[name])
            if raw is not None:
                self._int(where, name, raw)
        self._apply_motor(m)
        self._publish_position(m)

    def _poll_command(self, m):
        attr = m.attrs['command']
        sig = self._command_sig(attr)
        if sig != attr.sig:
            attr.sig = sig
            cmd = self._choice('port %s' % m.port, 'command', sig[0], MOTOR_COMMANDS) if sig[0] else None
            if cmd is not None:
                m.command = cmd
                m.running = cmd == 'run-direct'
                if cmd == 'reset':
                    m.reset_offset = m.hw_counts
                elif cmd not in ('run-direct', 'stop'):
                    self._error('port %s' % m.port, 'command', sig[0], 'not simulated by the fake')

    def _poll_duty(self, m):
        raw = self._read_client(m.attrs['duty_cycle_sp'])
        if raw is not None:
            value = self._int('port %s' % m.port, 'duty_cycle_sp', raw, _DUTY_LIMIT)
            if value is not None:
                m.duty_sp = value

    def _apply_motor(self, m):
        m.duty = m.sign() * m.duty_sp if m.running else 0
        attrs = m.attrs
        self._put(attrs['duty_cycle'], str(m.duty))
        if m.running:
            state = 'running'
        elif m.command == 'stop' and m.stop_action == 'hold':
            state = 'holding'
        else:
            state = ''
        self._put(attrs['state'], state)

    def _poll_gyro(self, g):
        raw = self._read_client(g.attrs['mode'])
        if raw is None:
            return
        mode = self._choice('port %s' % g.port, 'mode', raw, GYRO_MODE_NAMES)
        if mode is None or mode == g.mode:
            return
        if mode in _ANGLE_MODES:
            g.angle_ref = g.angle
        g.mode = mode
        if self.now_s is not None and self.gyro_mode_switch_s > 0:
            g.stale_until_s = self.now_s + self.gyro_mode_switch_s
        self._publish_gyro_mode(g)

    def poll(self, t_s=None):
        """Apply what clients wrote since the last poll; return {motor port: MotorState}.
        ``t_s``: the driver's time now (s), for the gyro's mode switch delay."""
        if t_s is not None:
            self.now_s = t_s
        for m in self._motors.values():
            self._poll_motor(m)
        if self._gyro is not None:
            self._poll_gyro(self._gyro)
        return {port: m.state() for port, m in self._motors.items()}

    def set_time(self, t_s):
        """The driver's time now (s), as poll(t_s) gives it, without polling (the gyro's
        mode switch delay runs on it)."""
        self.now_s = t_s

    def poll_attribute(self, relpath, t_s=None):
        """What :meth:`poll` does, for one attribute a client just wrote (``relpath`` as
        CountingIO names it): a driver that sees every write (hostsim.world.brick_timing)
        applies each at its own moment without re-reading the whole tree. -> the motor
        port it changed, or None."""
        if t_s is not None:
            self.now_s = t_s
        dev = self._by_relpath.get(relpath)
        if dev is None:
            return None
        if dev is self._gyro:
            self._poll_gyro(dev)
            return None
        if relpath.endswith('/duty_cycle_sp'):
            self._poll_duty(dev)
            self._apply_motor(dev)
        elif relpath.endswith('/command'):
            self._poll_command(dev)
            self._apply_motor(dev)
        else:
            self._poll_motor(dev)
        return dev.port

    def write_cost(self, relpath, data):
        """(seconds the write blocks, errno it fails with or None), as the driver would: only a
        gyro mode write to another mode costs (see the class docstring)."""
        g = self._gyro
        if g is None or self._by_relpath.get(relpath) is not g or not relpath.endswith('/mode'):
            return 0.0, None
        if self.gyro_mode_timeout:
            return GYRO_MODE_TRY_S * GYRO_MODE_TRIES, errno.ETIMEDOUT
        if parse_choice(bytes(data), GYRO_MODE_NAMES) in (None, g.mode):
            return 0.0, None
        return self.gyro_mode_write_s, None

    # ----------------------------------------------------------------- queries
    def lights(self):
        """{'left': color, 'right': color} the status lights show now ('off', 'green', 'amber',
        'red'; a brightness that is neither 0 nor max_brightness counts as on)."""
        on = []
        for led in self._lights:
            raw = os.pread(led.attrs['brightness'].fd, 64, 0)
            try:
                on.append(1 if int(_first_line(raw)) > 0 else 0)
            except ValueError:
                on.append(0)
        return {'left': lights_speaker.COLOR_NAMES[tuple(on[0:2])], 'right': lights_speaker.COLOR_NAMES[tuple(on[2:4])]}

    def tones(self, start=0):
        """[(t_s, Hz)] of the tone events written to the speaker so far, from the start-th on
        (0 Hz: silence); t_s is the writer's clock (tipbot_fw.io.lights_speaker writes time.monotonic())."""
        size = lights_speaker.INPUT_EVENT.size
        data = os.pread(self._speaker_fd, 1 << 24, start * size)
        out = []
        for at in range(0, len(data) - size + 1, size):
            sec, usec, kind, code, value = lights_speaker.INPUT_EVENT.unpack_from(data, at)
            if kind == lights_speaker.EV_SND and code == lights_speaker.SND_TONE:
                out.append((sec + usec * 1e-6, value))
        return out

    def motor_duty(self, port):
        """Duty (percent) applied at the last poll: 0 unless running run-direct."""
        return self._motor(port).duty

    def motor_running(self, port):
        return self._motor(port).running

    def motor_state(self, port):
        return self._motor(port).state()

    @property
    def gyro_mode(self):
        return None if self._gyro is None else self._gyro.mode

    def device_path(self, port):
        """The device directory of a motor port, the gyro port or 'battery'."""
        if port == 'battery':
            return self._battery.path
        if self._gyro is not None and port == self._gyro.port:
            return self._gyro.path
        return self._motor(port).path

    def attribute_path(self, port, name):
        return os.path.join(self.device_path(port), name)

    def relpath(self, port, name):
        """Path of an attribute relative to the root, as CountingIO names it."""
        return os.path.relpath(self.attribute_path(port, name), self.sysfs_root)

    # ----------------------------------------------------------------- failures, cleanup
    def remove_attribute(self, port, name):
        """Delete one attribute file (clients that open it later fail; fds already open keep
        reading the old file, so use CountingIO.fail for failures during a run)."""
        os.unlink(self.attribute_path(port, name))

    def close(self):
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds = []
        if self._own_root:
            shutil.rmtree(self.sysfs_root, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def file_mode(path):
    """Permission bits of a file (for tests comparing with sysfs)."""
    return stat.S_IMODE(os.stat(path).st_mode)
