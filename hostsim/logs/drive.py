"""Drive the robot from the keyboard: speed and turn commands over UDP to a run's --remote.

    python -m hostsim drive --to ADDRESS [--port 5006] [--rate-hz 20] [-- COMMAND ...]
    make drive HOST=robot@ev3dev.local        (starts `make run` with --remote and drives it)

Keys (arrows or WASD): up / w faster forward, down / s slower (then backwards), left / a turn
left, right / d turn right, space: stop (speed and turn to zero), q: quit. Each press changes the
speed by SPEED_STEP_MPS or the turn by YAW_STEP_DPS; the firmware clips both to its gains' limits
and ramps to them (tipbot_fw.drive.remote). The command is sent RATE_HZ times a second with a rising
sequence number; once this program stops sending, the robot comes to rest within 0.3 s and keeps
balancing. With COMMAND (make drive: the run on the brick), q and Ctrl-C end it, as Ctrl-C ends a
`make run`: the firmware stops the motors and writes its log.

Without a terminal the keys are read from standard input as characters (scripts, tests); when
that input ends, the last command stays until COMMAND ends.
"""
import argparse
import os
import select
import signal
import socket
import subprocess
import sys
import time

import hostsim
from hostsim.errors import TipbotError
from tipbot_fw.drive.remote import COMMAND, MAGIC, SEQ_MODULUS

DEFAULT_PORT = 5006
RATE_HZ = 20.0
SPEED_STEP_MPS = 0.05
YAW_STEP_DPS = 15.0
# key -> (speed change, turn change); None: stop
KEYS = {"w": (1, 0), "s": (-1, 0), "a": (0, 1), "d": (0, -1),
        "\x1b[A": (1, 0), "\x1b[B": (-1, 0), "\x1b[D": (0, 1), "\x1b[C": (0, -1), " ": None}


class DriveError(TipbotError):
    """An address or port that cannot be used."""


class Keys(object):
    """Key presses from a file descriptor (a terminal in cbreak mode, or a pipe)."""

    def __init__(self, fd):
        self.fd = fd
        self.saved = None
        self.buf = ""
        if os.isatty(fd):
            import termios
            import tty
            self.saved = termios.tcgetattr(fd)
            tty.setcbreak(fd)       # keys as they are pressed, output as usual

    def read(self, timeout_s):
        """The keys pressed within timeout_s ('' at the end of a pipe's input stays '')."""
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if not ready:
            return []
        data = os.read(self.fd, 64).decode("utf-8", "replace")
        if not data:
            return None             # end of input
        self.buf += data
        keys = []
        while self.buf:
            if self.buf.startswith("\x1b"):
                if len(self.buf) < 3:
                    break
                keys.append(self.buf[:3])
                self.buf = self.buf[3:]
            else:
                keys.append(self.buf[0])
                self.buf = self.buf[1:]
        return keys

    def close(self):
        if self.saved is not None:
            import termios
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)


def apply_key(state, key):
    """(speed_mps, yaw_dps) after a key; 'q' is handled by the caller."""
    step = KEYS.get(key.lower() if len(key) == 1 else key, ())
    if step is None:
        return 0.0, 0.0
    if not step:
        return state
    return (round(state[0] + step[0] * SPEED_STEP_MPS, 3), round(state[1] + step[1] * YAW_STEP_DPS, 3))


def drive(address, port, keys, rate_hz=RATE_HZ, child=None, say=print):
    """Send the keys' commands until q, the end of the keys' input or the child's end."""
    try:
        target = socket.getaddrinfo(address, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4]
    except (OSError, UnicodeError) as e:
        raise DriveError("drive: %s: %s" % (address, e))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    # The count starts at the clock's milliseconds: at RATE_HZ it falls behind the clock, so a
    # drive program started again during a run is ahead of the one before it (the firmware obeys
    # only numbers after the last obeyed, modulo 2**32: tipbot_fw.drive.remote.is_after).
    state, period = (0.0, 0.0), 1.0 / rate_hz
    seq = int(time.time() * 1000.0) % SEQ_MODULUS
    sent = 0
    next_send = time.monotonic()
    shown = None
    ended = False               # the keys' input ended (a script's): the command stays, the run goes on
    try:
        while child is None or child.poll() is None:
            wait = max(0.0, next_send - time.monotonic())
            pressed = keys.read(wait) if not ended else (time.sleep(wait) or [])
            if pressed is None:
                if child is None:
                    break
                ended, pressed = True, []
            if "q" in pressed:
                break
            for key in pressed:
                state = apply_key(state, key)
            if state != shown:
                say("drive: speed %+.2f m/s, turn %+.0f deg/s" % state)
                shown = state
            if time.monotonic() >= next_send:
                seq, sent = (seq + 1) % SEQ_MODULUS, sent + 1
                try:
                    sock.sendto(COMMAND.pack(MAGIC, seq, state[0], state[1]), target)
                except OSError:
                    pass            # nobody listening yet (the run starting): the next one
                next_send += period
    finally:
        sock.close()
    return sent


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    command = []
    if "--" in argv:
        i = argv.index("--")
        argv, command = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(prog=hostsim.command("drive"), description=__doc__.split("\n\n")[0])
    ap.add_argument("--to", metavar="ADDRESS", required=True, help="the brick's address (the run's host)")
    ap.add_argument("--port", type=int, default=DEFAULT_PORT, help="the run's --remote port (default %(default)s)")
    ap.add_argument("--rate-hz", type=float, default=RATE_HZ, help="commands per second (default %(default)s)")
    args = ap.parse_args(argv)
    child = subprocess.Popen(command) if command else None
    keys = Keys(sys.stdin.fileno())
    print("drive: arrows or WASD to drive, space to stop, q to quit (commands to %s:%d)" % (args.to, args.port),
          file=sys.stderr)
    try:
        drive(args.to, args.port, keys, args.rate_hz, child, say=lambda m: print(m, file=sys.stderr))
    except KeyboardInterrupt:
        pass
    except DriveError as e:
        print(e, file=sys.stderr)
        return 2
    finally:
        keys.close()
        if child is not None and child.poll() is None:
            child.send_signal(signal.SIGINT)        # as Ctrl-C in `make run`: motors stopped, log written
    return child.wait() if child is not None else 0
