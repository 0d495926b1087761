"""What the robot tells its owner while it starts: hold it still, then let go. One place for it.

Held exactly at the start pose the estimate is zero and the wheels do not move, so "let go
when the wheels drive" cannot be the cue: the firmware says when. Today the cue is text,
written to stdout (brickrun and brickman's File Browser show a program's stdout on the brick's
screen) and to stderr (with the firmware's other messages, over ssh: `make run`); once if both
are the same terminal. The EV3's LEDs and tones (a later issue) belong in these methods too.
"""
import os
import sys


class OwnerCues(object):
    """``streams``: where the text goes; None: sys.stdout and sys.stderr as they are when a cue
    is given; () for no text (simulations)."""

    def __init__(self, streams=None):
        self.streams = streams

    def hold_still(self, seconds):
        """Before the gyro calibration: the robot must be held still and upright."""
        self._show('HOLD the robot still and upright: calibrating the gyro ({:.1f} s)'.format(seconds))

    def let_go(self):
        """The calibration is done and the first control tick comes next."""
        self._show('LET GO NOW: balancing')

    def _show(self, text):
        line = 'tipbot: {}\n'.format(text)
        for stream in self._targets():
            try:
                stream.write(line)
                stream.flush()
            except (OSError, ValueError):    # a closed or vanished console must not stop the start
                pass

    def _targets(self):
        if self.streams is not None:
            return self.streams
        out, err = sys.stdout, sys.stderr
        if out is None or err is None or _same_file(out, err):
            return [s for s in (err, out) if s is not None][:1]
        return [out, err]


def _same_file(a, b):
    try:
        return os.path.samestat(os.fstat(a.fileno()), os.fstat(b.fileno()))
    except (AttributeError, OSError, ValueError):    # no file descriptor (captured output)
        return False


QUIET = OwnerCues(streams=())
