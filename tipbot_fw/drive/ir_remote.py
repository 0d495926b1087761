"""Driving from the EV3 IR remote (lego-ev3-ir in IR-REMOTE mode), tank style.

When the configuration names the IR sensor's port (`ports.ir_remote`; `ir_remote_channel` the
red slider's channel, 1-4) and the run has no --course or --remote, `run` drives by the remote's
buttons as ev3dev2's GyroBalancer does: the red buttons (left side of the remote) drive the
left wheel, the blue ones (right side) the right wheel, up forward, down back. Both up: forward
at the top speed of the gains; red up and blue down: turn in place to the right at the top yaw
rate; one button alone: half the speed and half the yaw rate (an arc about the other wheel).

The remote sends only while a button is held and the sensor reads 0 when none is
(../shared/ev3-hardware.md): releasing every button is the stop command; the robot comes
smoothly to rest and keeps balancing. A read that fails or gives a code outside 0-11 counts as
no button (and is counted, for the run's summary).

The sensor is read in the loop's slack (a side task, as tipbot_fw.drive.remote's receiver is), at most
every READ_PERIOD_S: a sysfs read costs 0.3-0.45 ms, the tick never pays it. Same interface as
tipbot_fw.drive.remote.Receiver (poll, summary, close, host), so the live plan is the same.

Python 3.5, standard library.
"""
import math

READ_PERIOD_S = 0.05        # 20 reads a second: faster than a thumb, slower than the ticks by 10
# IR-REMOTE codes -> (left wheel, right wheel) commands, each -1, 0 or +1 (ev3-hardware.md):
# 1 red up, 2 red down, 3 blue up, 4 blue down, 5 red up + blue up, 6 red up + blue down,
# 7 red down + blue up, 8 red down + blue down, 9 the beacon (no drive), 10 both red, 11 both blue
WHEELS = {0: (0, 0), 1: (1, 0), 2: (-1, 0), 3: (0, 1), 4: (0, -1), 5: (1, 1), 6: (1, -1),
          7: (-1, 1), 8: (-1, -1), 9: (0, 0), 10: (0, 0), 11: (0, 0)}


def command(code, speed_mps, yaw_rate_rad_s):
    """(speed m/s, yaw rate rad/s, positive to the left) of a button code, at the given top
    speed and yaw rate: the mean and half the difference of the wheels' commands."""
    left, right = WHEELS.get(code, (0, 0))
    return 0.5 * (left + right) * speed_mps, 0.5 * (right - left) * yaw_rate_rad_s


class IrRemote(object):
    """The remote's buttons as commands; poll(now_s) -> (speed_mps, yaw_rate_rad_s) now.

    read() -> the channel's code (an int; it may raise OSError); limits: the gains' drive limits
    (speed_mps, yaw_rate_dps); where: what the log header names as the command source."""

    def __init__(self, read, limits, where):
        self.read = read
        self.top = (float(limits['speed_mps']), math.radians(limits['yaw_rate_dps']))
        self.host = where
        self.next_s = None
        self.code = 0
        self.presses = 0            # reads that saw a button
        self.failed = 0             # reads that failed or gave an unknown code

    def poll(self, now_s):
        if self.next_s is None or now_s >= self.next_s:
            self.next_s = now_s + READ_PERIOD_S
            try:
                code = int(self.read())
            except (OSError, ValueError):
                code = -1
            if code not in WHEELS:
                self.failed += 1
                code = 0
            elif code:
                self.presses += 1
            self.code = code
        return command(self.code, self.top[0], self.top[1])

    def summary(self):
        return {'host': self.host, 'obeyed': self.presses, 'dropped': {'failed reads': self.failed}}

    def close(self):
        pass
