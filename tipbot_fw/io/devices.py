"""The device interface the control loop talks to, and an in-memory implementation.

Raw readings cross this interface untouched (counts and integer gyro units, no polarity, no
offsets): the core (tipbot_fw.cores) makes every conversion, so a log of raw readings replays exactly.
"""


class Devices(object):
    """Interface (docs/architecture.md). Motor order everywhere: right wheel, left wheel, th2, th3."""

    # Encoder counts per motor revolution, in motor order; implementations read `count_per_rot`.
    counts_per_rot = (360, 360, 360, 360)

    def read_raw(self):
        """-> ((enc_r, enc_l, enc_2, enc_3) counts, (gyro_angle_deg, gyro_rate_dps)), all ints.
        On the brick: 5 sysfs reads, the 4 encoders' `position` and the gyro's `bin_data`."""
        raise NotImplementedError

    def write_duties(self, duties):
        """4 ints in [-100, 100] (r, l, th2, th3), already signed for the motor; writes only changed ones."""
        raise NotImplementedError

    def read_battery_v(self):
        """Battery voltage (float V); called at start and about once per second outside the tick."""
        raise NotImplementedError

    def stop_all(self):
        """Duty 0 and the stop command on every motor. Must never raise."""
        raise NotImplementedError

    def close(self):
        pass

    # The EV3 IR remote, when the configuration has one (tipbot_fw.drive.ir_remote): (port, channel),
    # and read_ir_remote() -> its button code, an int (read outside the tick).
    ir_remote = None


class MemoryDevices(Devices):
    """In-memory devices for tests and the bench.

    Readings come from source() -> (enc4, gyro2) when a callable is given (it may raise to
    simulate a failed read), else from the settable attributes `enc` and `gyro`. battery_v is
    a float or a callable returning one. Counters: raw_reads (read_raw calls), duty_writes
    (individual duty values written, i.e. changed ones), write_calls, battery_reads, stop_calls.
    If `trace` is a list, every operation appends its name to it. write_duties refuses (ValueError)
    anything but 4 ints in [-100, 100], as a check on the firmware. An IR remote: set `ir_remote`
    ((port, channel)) and `ir_code` (an int, or a callable returning one; it may raise).
    """

    def __init__(self, source=None, battery_v=8.0, counts_per_rot=(360, 360, 360, 360)):
        self.source = source
        self.enc = (0, 0, 0, 0)
        self.gyro = (0, 0)
        self.battery_v = battery_v
        self.counts_per_rot = tuple(counts_per_rot)
        self.duties = [0, 0, 0, 0]
        self.raw_reads = 0
        self.duty_writes = 0
        self.write_calls = 0
        self.battery_reads = 0
        self.stop_calls = 0
        self.closed = False
        self.trace = None
        self.ir_code = 0

    def read_raw(self):
        self.raw_reads += 1
        if self.trace is not None:
            self.trace.append('read_raw')
        if self.source is not None:
            return self.source()
        return self.enc, self.gyro

    def write_duties(self, duties):
        self.write_calls += 1
        if self.trace is not None:
            self.trace.append('write_duties')
        if len(duties) != 4:
            raise ValueError('write_duties needs 4 duties, got {!r}'.format(duties))
        for d in duties:
            if type(d) is not int or not -100 <= d <= 100:
                raise ValueError('duty {!r} is not an int in [-100, 100]'.format(d))
        last = self.duties
        for i in range(4):
            if duties[i] != last[i]:
                last[i] = duties[i]
                self.duty_writes += 1

    def read_battery_v(self):
        self.battery_reads += 1
        if self.trace is not None:
            self.trace.append('read_battery_v')
        b = self.battery_v
        return b() if callable(b) else b

    def stop_all(self):
        self.stop_calls += 1
        if self.trace is not None:
            self.trace.append('stop_all')
        self.duties = [0, 0, 0, 0]

    def read_ir_remote(self):
        c = self.ir_code
        return c() if callable(c) else c

    def close(self):
        self.closed = True
