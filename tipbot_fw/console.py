"""What the firmware tells its owner: one line on stderr, prefixed ``tipbot:``.

stdout is left to what a command prints as its result (check, calibrate, bench). A console that
went away (the ssh session of `make run` dropped: EPIPE, since Python ignores SIGPIPE) must not
turn a message into an error in the middle of a stop: the message is then lost, nothing else.
"""
import sys


def say(msg):
    try:
        sys.stderr.write('tipbot: {}\n'.format(msg))
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass
