"""The real EV3 device layer (the Devices interface of tipbot_fw.io.devices).

Start-up uses python-ev3dev2 to find each device by its port and check its driver, then sets
the devices up once. The 5 ms control tick uses only file descriptors opened once, with
``pread``/``pwrite`` at offset 0 (sysfs regenerates a value on every read at offset 0):

* read_raw: 4 reads of ``position`` + 1 read of the gyro's ``bin_data`` (mode GYRO-G&A: angle
  and rate as two little-endian s16, read together so both come from the same sample);
* write_duties: one write of ``duty_cycle_sp`` per motor whose duty changed (0 to 4 writes).

What crosses the interface is raw (tipbot_fw.io.devices): counts as the encoder counts them, the
gyro as the sensor reports it, duties already signed for each motor. Polarity, encoder zeros
and the gyro sign belong to the signal chain. For the counts to be the encoder's own, the sysfs
``polarity`` (which negates both position and duty in the driver) is set to ``normal`` at start,
overwriting whatever another program left there.

Start-up, per motor: duty_cycle_sp 0, stop_action (config, default coast), polarity normal,
command run-direct; then the gyro mode GYRO-G&A, once (a mode write can block for tens of ms,
so it never happens in the tick). No ``reset`` command: the signal chain takes the encoder zeros
from its first reading, and a reset would zero the counters at a moment a slow observer (the
fake EV3 driven by another process) chooses, possibly after that first reading; every setting
run-direct depends on is written explicitly instead.

The gyro: setting the mode restarts its angle from 0 and, on older sensors, calibrates it, so
the robot must be still then; the first samples after the mode write may still be the previous
mode's (tens of ms), which the gyro calibration at start absorbs.

After :meth:`Ev3Devices.stop_all` the motors stay stopped: write_duties only changes
``duty_cycle_sp``, never the command. :meth:`Ev3Devices.close` stops them too, since a motor in
run-direct keeps its last duty after the program ends.

``config`` is the validated configuration (tipbot_fw.config); used: ``ports``, ``drivers``
(each for right_wheel, left_wheel, joint2, joint3, gyro, and ir_remote if its port is set, with
``ir_remote_channel``: mode IR-REMOTE set at start, its channel's value read outside the tick by
read_ir_remote) and, if present, ``stop_action``.

Errors: Ev3SetupError at start (every missing or wrong device, one line each); during the run
Ev3ReadError / Ev3WriteError, which are OSErrors naming the port and attribute.

Python 3.5 + the standard library (python-ev3dev2 is imported at start-up only).
"""

import os
import struct

from tipbot_fw.vocabulary import MOTOR_ROLES
from tipbot_fw.console import say   # (not logging: its modules are memory the brick does not spare)

GYRO_ROLE = 'gyro'
GYRO_MODE = 'GYRO-G&A'
IR_ROLE = 'ir_remote'
IR_MODE = 'IR-REMOTE'
STOP_ACTIONS = ('coast', 'brake')
DEFAULT_STOP_ACTION = 'coast'
DUTY_LIMIT = 100
BATTERY_PATH = 'power_supply/lego-ev3-battery/voltage_now'

# A sysfs integer is at most 12 bytes ("-2147483648\n"); asking for more costs nothing.
_READ_BYTES = 32
_GYRO = struct.Struct('<hh')

# The bytes written for each allowed duty: a dict lookup is cheaper than formatting on the
# brick, and a duty out of range or not integral misses it instead of being written truncated.
_DUTY_BYTES = dict((d, ('%d\n' % d).encode('ascii')) for d in range(-DUTY_LIMIT, DUTY_LIMIT + 1))



class Ev3DeviceError(Exception):
    """Base of the device layer's errors."""


class Ev3SetupError(Ev3DeviceError):
    """A device is missing, is the wrong kind, or could not be set up (nothing runs).

    ``problems`` has one line per fault, each starting with the port, e.g.
    ``port outD: expected lego-ev3-m-motor, found lego-ev3-l-motor``.
    """

    def __init__(self, problems, fields=None):
        self.problems = list(problems)
        # the configuration field each problem comes from ('drivers.joint3'), or None
        self.fields = list(fields) if fields is not None else [None] * len(self.problems)
        Ev3DeviceError.__init__(self, 'EV3 devices not ready:\n  ' + '\n  '.join(self.problems))

    def one_line(self, source):
        """The problems on one line, each named by the file and field it comes from (``source``:
        the configuration file, or the words for the defaults)."""
        return '; '.join(p if f is None else '{}: field {}: {}'.format(source, f, p)
                         for p, f in zip(self.problems, self.fields))


class Ev3IOError(Ev3DeviceError, OSError):
    """A sysfs read or write failed during the run. An OSError, so that callers handling
    device failures as OSError (tipbot_fw.loop) see it; ``errno`` is the cause's."""

    def __init__(self, port, attribute, action, cause):
        OSError.__init__(self, 'port {}: {} {} failed: {}'.format(port, action, attribute, cause))
        self.errno = getattr(cause, 'errno', None)
        self.port = port
        self.attribute = attribute


class Ev3ReadError(Ev3IOError):
    pass


class Ev3WriteError(Ev3IOError):
    pass


def short_port(address):
    """'ev3-ports:outA' -> 'outA' (ev3dev-stretch prefixes EV3 port names with 'ev3-ports:')."""
    if address.startswith('ev3-ports:'):
        return address[len('ev3-ports:'):]
    return address


def ir_spec(config):
    """(port, driver, channel) of the configured IR remote's sensor, or None."""
    port = (config.get('ports') or {}).get(IR_ROLE)
    if port is None:
        return None
    return short_port(port), config['drivers'][IR_ROLE], config['ir_remote_channel']


def device_spec(config):
    """-> (motors, gyro, stop_action) from config: motors = [(port, driver)] in MOTOR_ROLES
    order, gyro = (port, driver). Raises Ev3SetupError for missing fields."""
    problems = []

    def field(group, role):
        try:
            return config[group][role]
        except (KeyError, TypeError):
            problems.append('config: missing field {}.{}'.format(group, role))
            return ''

    motors = [(short_port(field('ports', r)), field('drivers', r)) for r in MOTOR_ROLES]
    gyro = (short_port(field('ports', GYRO_ROLE)), field('drivers', GYRO_ROLE))
    stop_action = config.get('stop_action', DEFAULT_STOP_ACTION)
    if stop_action not in STOP_ACTIONS:
        problems.append('config: stop_action must be one of {}, not {!r}'.format(
            ', '.join(STOP_ACTIONS), stop_action))
    if problems:
        raise Ev3SetupError(problems)
    return motors, gyro, stop_action


def survey(ev3dev2, class_name, pattern):
    """{short port: (device dir, driver_name)} of every device of a sysfs class, read through
    python-ev3dev2 (whose DEVICE_ROOT_PATH the caller has set, see under_root). Exact ports:
    ev3dev2's own address match is a substring match ('in2' would also match 'in2:i2c80:mux1')."""
    classpath = os.path.abspath(ev3dev2.Device.DEVICE_ROOT_PATH + '/' + class_name)
    found = {}
    for name in ev3dev2.list_device_names(classpath, pattern):
        dev = ev3dev2.Device(class_name, name, name_exact=True)
        _, address = dev.get_attr_string(None, 'address')
        _, driver = dev.get_attr_string(None, 'driver_name')
        found[short_port(address)] = (classpath + '/' + name, driver)
    return found


def _check(found, port, driver, kind, role, problems, fields):
    """The device dir on ``port`` if it has ``driver``, else None with the problem noted (and
    the configuration field it comes from: the port's, or the driver's)."""
    if port not in found:
        problems.append('port {}: no {} found (expected {})'.format(port, kind, driver))
        fields.append('ports.' + role)
        return None
    path, actual = found[port]
    if actual != driver:
        problems.append('port {}: expected {}, found {}'.format(port, driver, actual))
        fields.append('drivers.' + role)
        return None
    return path


class under_root(object):
    """``with under_root(sysfs_root) as ev3dev2:`` python-ev3dev2, imported late (only the brick
    has it), with its Device.DEVICE_ROOT_PATH set to sysfs_root, restored on leaving."""

    def __init__(self, sysfs_root):
        self.sysfs_root = sysfs_root

    def __enter__(self):
        import ev3dev2
        self.ev3dev2 = ev3dev2
        self.saved = ev3dev2.Device.DEVICE_ROOT_PATH
        ev3dev2.Device.DEVICE_ROOT_PATH = self.sysfs_root
        return ev3dev2

    def __exit__(self, *exc):
        self.ev3dev2.Device.DEVICE_ROOT_PATH = self.saved


def count_per_rot(ev3dev2, device_dir):
    """sysfs ``count_per_rot`` of the tacho motor in device_dir."""
    dev = ev3dev2.Device('tacho-motor', os.path.basename(device_dir), name_exact=True)
    return dev.get_attr_int(None, 'count_per_rot')[1]


def discover(config, sysfs_root='/sys/class'):
    """Find the configured devices with python-ev3dev2 and check their drivers.

    -> ({port: device dir}, counts_per_rot of the 4 motors); Ev3SetupError lists every fault."""
    motors, gyro, _ = device_spec(config)
    with under_root(sysfs_root) as ev3dev2:
        found_motors = survey(ev3dev2, 'tacho-motor', 'motor*')
        found_sensors = survey(ev3dev2, 'lego-sensor', 'sensor*')
        problems, fields = [], []
        paths = {}
        for role, (port, driver) in zip(MOTOR_ROLES, motors):
            path = _check(found_motors, port, driver, 'motor', role, problems, fields)
            if path:
                paths[port] = path
        sensors = [(GYRO_ROLE, gyro[0], gyro[1], GYRO_MODE)]
        ir = ir_spec(config)
        if ir is not None:
            sensors.append((IR_ROLE, ir[0], ir[1], IR_MODE))
        for role, port, driver, mode in sensors:
            path = _check(found_sensors, port, driver, 'sensor', role, problems, fields)
            if path:
                paths[port] = path
                dev = ev3dev2.Device('lego-sensor', os.path.basename(path), name_exact=True)
                _, modes = dev.get_attr_set(None, 'modes')
                if mode not in modes:
                    problems.append('port {}: sensor has no {} mode (modes: {})'.format(port, mode, ' '.join(modes)))
                    fields.append('drivers.' + role)
        if problems:
            raise Ev3SetupError(problems, fields)
        return paths, tuple(count_per_rot(ev3dev2, paths[port]) for port, _ in motors)


class SysfsDevices(object):
    """What the firmware's sysfs device layers share (Ev3Devices for the robot,
    tipbot_fw.identify.SingleMotor for one motor): file descriptors opened once, set-up writes
    that name the port and attribute, the battery reading, and close() that stops the motors
    before it closes the descriptors.

    ``io`` provides open/pread/pwrite/close with the signatures of :mod:`os` (the default);
    tests pass a counting one. A subclass opens its attributes with _open_attr, then calls
    _opened(), and implements stop_all() with _stop_writes().
    """

    def __init__(self, io=os):
        self._io = io
        self._pread = io.pread
        self._pwrite = io.pwrite
        self._fds = []
        self._closed = False
        self._open_problems = []
        self._battery_fd = -1

    def _open_attr(self, port, name, flags, path):
        """An fd of the attribute at path, or -1 with the problem noted for _opened()."""
        try:
            fd = self._io.open(path, flags)
        except OSError as e:
            self._open_problems.append('port {}: cannot open {}: {}'.format(port, name, e))
            return -1
        self._fds.append(fd)
        return fd

    def _open_battery(self, sysfs_root):
        self._battery_fd = self._open_attr('battery', BATTERY_PATH, os.O_RDONLY,
                                           sysfs_root + '/' + BATTERY_PATH)

    def _opened(self):
        """Ev3SetupError listing every attribute _open_attr could not open."""
        if self._open_problems:
            raise Ev3SetupError(self._open_problems)

    def _setup_write(self, port, name, fd, text):
        try:
            self._pwrite(fd, (text + '\n').encode('ascii'), 0)
        except OSError as e:
            raise Ev3SetupError(['port {}: writing {} {!r} failed: {}'.format(port, name, text, e)])

    def _write_once(self, port, device_dir, name, text):
        """Open, write and close a set-up attribute (stop_action, polarity, mode)."""
        try:
            fd = self._io.open(device_dir + '/' + name, os.O_WRONLY)
        except OSError as e:
            raise Ev3SetupError(['port {}: cannot open {}: {}'.format(port, name, e)])
        try:
            self._setup_write(port, name, fd, text)
        finally:
            self._io.close(fd)

    def read_battery_v(self):
        """Battery voltage in volts (sysfs gives microvolts)."""
        try:
            return int(self._pread(self._battery_fd, _READ_BYTES, 0)) * 1e-6
        except (OSError, ValueError) as e:
            raise Ev3ReadError('battery', 'voltage_now', 'reading', e)

    def _stop_writes(self, writes, during):
        """Each (port, attribute, fd, bytes) written, whatever fails. -> the failures as strings."""
        failures = []
        for port, name, fd, data in writes:
            if fd < 0:
                continue
            try:
                self._pwrite(fd, data, 0)
            except Exception as e:  # stopping must go on, whatever went wrong
                failures.append('port {}: writing {} during {} failed: {}'.format(port, name, during, e))
        return failures

    def stop_all(self):
        """Stop every motor. Never raises; idempotent. -> the failures as strings."""
        raise NotImplementedError

    def _forget_fds(self):
        """After close: the subclass drops its descriptors, so stop_all writes nothing."""

    def close(self):
        """Stop the motors (failures logged), then close every descriptor. Idempotent."""
        if self._closed:
            return
        self._closed = True
        for failure in self.stop_all():
            say(failure)
        fds, self._fds = self._fds, []
        for fd in fds:
            try:
                self._io.close(fd)
            except OSError as e:
                say('closing fd {}: {}'.format(fd, e))
        self._battery_fd = -1
        self._forget_fds()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Ev3Devices(SysfsDevices):
    """Devices on an ev3dev sysfs tree (the real /sys/class, or hostsim.world.fake_ev3's).

    ``io`` provides open/pread/pwrite/close with the signatures of :mod:`os` (the default);
    tests pass a counting one. Raises Ev3SetupError naming every missing or wrong device;
    motors are left untouched then.

    After start-up: ``counts_per_rot`` (4 ints, sysfs ``count_per_rot``, motor order) and
    ``paths`` ({port: sysfs device dir}, for the log header).
    """

    def __init__(self, config, sysfs_root='/sys/class', io=os):
        SysfsDevices.__init__(self, io)
        self._duty_fds = ()
        self._cmd_fds = ()
        self._last = [0, 0, 0, 0]
        motors, gyro, stop_action = device_spec(config)
        self._motor_ports = tuple(port for port, _ in motors)
        self._gyro_port = gyro[0]
        self._ir = ir_spec(config)
        self._ir_fd = -1
        self.paths, self.counts_per_rot = discover(config, sysfs_root)
        try:
            self._open(sysfs_root)
            self._set_up(stop_action)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ start-up
    def _open(self, sysfs_root):
        def open_attr(port, name, flags):
            return self._open_attr(port, name, flags, self.paths[port] + '/' + name)

        ports = self._motor_ports
        pos = tuple(open_attr(p, 'position', os.O_RDONLY) for p in ports)
        duty = tuple(open_attr(p, 'duty_cycle_sp', os.O_WRONLY) for p in ports)
        cmd = tuple(open_attr(p, 'command', os.O_WRONLY) for p in ports)
        gyro = open_attr(self._gyro_port, 'bin_data', os.O_RDONLY)
        if self._ir is not None:    # the channel's button code: value0 for channel 1, ...
            self._ir_fd = open_attr(self._ir[0], 'value{}'.format(self._ir[2] - 1), os.O_RDONLY)
        self._open_battery(sysfs_root)
        self._opened()
        self._read_fds = pos + (gyro,)
        self._read_names = tuple((p, 'position') for p in ports) + ((self._gyro_port, 'bin_data'),)
        self._duty_fds = duty
        self._cmd_fds = cmd

    def _set_up(self, stop_action):
        for i, port in enumerate(self._motor_ports):
            self._setup_write(port, 'duty_cycle_sp', self._duty_fds[i], '0')
            self._write_once(port, self.paths[port], 'stop_action', stop_action)
            self._write_once(port, self.paths[port], 'polarity', 'normal')
            self._setup_write(port, 'command', self._cmd_fds[i], 'run-direct')
        self._write_once(self._gyro_port, self.paths[self._gyro_port], 'mode', GYRO_MODE)
        if self._ir is not None:
            self._write_once(self._ir[0], self.paths[self._ir[0]], 'mode', IR_MODE)

    # ------------------------------------------------------------------ the tick
    def read_raw(self):
        """-> ((enc_r, enc_l, enc_2, enc_3) counts, (gyro_angle_deg, gyro_rate_dps)), raw ints.
        5 reads; Ev3ReadError names the port and attribute that failed."""
        pread = self._pread
        fa, fb, fc, fd, fg = self._read_fds
        where = 0
        try:
            a = int(pread(fa, _READ_BYTES, 0))
            where = 1
            b = int(pread(fb, _READ_BYTES, 0))
            where = 2
            c = int(pread(fc, _READ_BYTES, 0))
            where = 3
            d = int(pread(fd, _READ_BYTES, 0))
            where = 4
            gyro = _GYRO.unpack(pread(fg, 4, 0))
        except (OSError, ValueError, struct.error) as e:
            port, name = self._read_names[where]
            raise Ev3ReadError(port, name, 'reading', e)
        return (a, b, c, d), gyro

    def write_duties(self, duties):
        """Duties (int percent in [-100, 100], signed for each motor) of r, l, th2, th3; writes
        only those changed since the last successful write. A failed motor is retried on the
        next call. Ev3WriteError on an OS failure, ValueError on a duty out of range.
        Unrolled, like read_raw: on the brick a loop over the four motors, with its indexing,
        costs more than the writes' own Python."""
        dr, dl, d2, d3 = duties
        last = self._last
        pwrite = self._pwrite
        fa, fb, fc, fd = self._duty_fds
        table = _DUTY_BYTES
        where = 0
        try:
            if dr != last[0]:
                pwrite(fa, table[dr], 0)
                last[0] = dr
            where = 1
            if dl != last[1]:
                pwrite(fb, table[dl], 0)
                last[1] = dl
            where = 2
            if d2 != last[2]:
                pwrite(fc, table[d2], 0)
                last[2] = d2
            where = 3
            if d3 != last[3]:
                pwrite(fd, table[d3], 0)
                last[3] = d3
        except KeyError:
            raise ValueError('port {}: duty {!r} is not an integer in [-{}, {}]'.format(
                self._motor_ports[where], duties[where], DUTY_LIMIT, DUTY_LIMIT))
        except OSError as e:
            raise Ev3WriteError(self._motor_ports[where], 'duty_cycle_sp', 'writing', e)

    # ------------------------------------------------------------------ outside the tick
    @property
    def ir_remote(self):
        """(port, channel) of the IR remote the configuration names, or None."""
        return None if self._ir is None else (self._ir[0], self._ir[2])

    def read_ir_remote(self):
        """The IR remote channel's button code (tipbot_fw.drive.ir_remote), one read; Ev3ReadError."""
        try:
            return int(self._pread(self._ir_fd, _READ_BYTES, 0))
        except (OSError, ValueError) as e:
            raise Ev3ReadError(self._ir[0], 'value{}'.format(self._ir[2] - 1), 'reading', e)

    def stop_all(self):
        """Duty 0, then command ``stop`` (applies stop_action), on every motor. Never raises; a
        failure on one motor or attribute does not keep the rest from stopping. Idempotent.
        -> the failures as strings."""
        writes = []
        for port, duty_fd, cmd_fd in zip(self._motor_ports, self._duty_fds, self._cmd_fds):
            writes += [(port, 'duty_cycle_sp', duty_fd, b'0\n'), (port, 'command', cmd_fd, b'stop\n')]
        self._last[:] = [0, 0, 0, 0]
        return self._stop_writes(writes, 'stop_all')

    def _forget_fds(self):
        self._duty_fds = self._cmd_fds = ()
