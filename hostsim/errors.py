"""Errors raised by the host-side tools.

Each carries a message that names the file, field or matrix at fault, so a command
line tool can print it as one line and exit non-zero.
"""


import json


class TipbotError(Exception):
    """Base class of the host tools' expected failures (bad input, impossible design)."""


class ParameterError(TipbotError):
    """A robot parameters file is missing a field or holds an invalid value."""


class DesignError(TipbotError):
    """A gain design cannot be carried out (uncontrollable, singular weight, ...)."""


def read_json(path, what, error):
    """The parsed JSON of a user's file; ``error`` (a TipbotError class) names the file and
    says whether it could not be read (``what``: e.g. "parameters file") or is not JSON."""
    try:
        with open(path) as f:
            return json.load(f)
    except OSError as exc:
        raise error("%s: cannot read %s: %s" % (path, what, exc.strerror or exc))
    except ValueError as exc:
        raise error("%s: not valid JSON: %s" % (path, exc))
