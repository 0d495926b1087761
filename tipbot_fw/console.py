"""What the firmware tells its owner: one line on stderr, prefixed ``tipbot:``.

stdout is left to what a command prints as its result (check, calibrate, bench).
"""
import sys


def say(msg):
    sys.stderr.write('tipbot: {}\n'.format(msg))
    sys.stderr.flush()
