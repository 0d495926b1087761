"""Checks of the fields of the JSON files the project reads, with one message format:

    <file>: field <dotted.name> <problem>

for example ``robot.json: field limits.th1_rad must be a number in (0, 1.5], got -1``. Used by
tipbot_fw.config and tipbot_fw.gains on the brick, and by the host's parameters and scenario
readers (hostsim.model.params, hostsim.sim.scenario), each with its own error class.

A checker is a function value -> problem (None when the value is fine); ``Fields`` binds a
file and an error class and raises on the first problem. Python 3.5, standard library only.
"""
import json
import math


def message(source, field, problem):
    """The one format of a bad field."""
    return '{}: field {} {}'.format(source, field, problem)


def is_number(v):
    """An int or float, not a bool (JSON's true is no number)."""
    return not isinstance(v, bool) and isinstance(v, (int, float))


def number(lo=None, hi=None, lo_open=True, integer=False, allow_null=False):
    """Checker of a finite number (an integer with integer=True) in (lo, hi] ([lo, hi] with
    lo_open=False; either bound may be None), or null with allow_null."""
    kind = 'an integer' if integer else ('a number' if lo is not None else 'a finite number')
    if lo is not None and hi is not None:
        kind += ' in {}{}, {}]'.format('(' if lo_open else '[', lo, hi)
    elif lo is not None:
        kind += ' {} {}'.format('>' if lo_open else '>=', lo)
    if allow_null:
        kind += ' or null'

    def check(v):
        if v is None and allow_null:
            return None
        if (not is_number(v) or (integer and not isinstance(v, int)) or not math.isfinite(v)
                or (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and v > hi)):
            return 'must be {}, got {!r}'.format(kind, v)
        return None
    return check


def one_of(*choices):
    def check(v):
        if isinstance(v, bool) or v not in choices:
            return 'must be one of {}, got {!r}'.format(', '.join(repr(c) for c in choices), v)
        return None
    return check


def string(v):
    if not isinstance(v, str):
        return 'must be a string, got {!r}'.format(v)
    return None


def nonempty_string(v):
    if not isinstance(v, str) or not v:
        return 'must be a non-empty string, got {!r}'.format(v)
    return None


def boolean(v):
    if not isinstance(v, bool):
        return 'must be true or false, got {!r}'.format(v)
    return None


def obj(v):
    if not isinstance(v, dict):
        return 'must be an object, got {!r}'.format(v)
    return None


def array(v):
    if not isinstance(v, list):
        return 'must be a list, got {!r}'.format(v)
    return None


def strings(n):
    """Checker of a list of n strings."""
    def check(v):
        if not isinstance(v, list) or len(v) != n or not all(isinstance(s, str) for s in v):
            return 'must be a list of {} strings, got {!r}'.format(n, v)
        return None
    return check


def numbers(n):
    """Checker of a list of n finite numbers."""
    def check(v):
        if not isinstance(v, list) or len(v) != n or not all(is_number(e) and math.isfinite(e) for e in v):
            return 'must be a list of {} finite numbers, got {!r}'.format(n, v)
        return None
    return check


def matrix(rows, cols):
    """Checker of a rows x cols matrix of finite numbers, as a list of rows."""
    def check(m):
        if not isinstance(m, list) or not all(isinstance(r, list) for r in m):
            return 'must be a list of rows (a {}x{} matrix)'.format(rows, cols)
        widths = set(len(r) for r in m)
        if len(widths) > 1:
            return 'has rows of different lengths {}'.format(sorted(widths))
        shape = (len(m), widths.pop() if widths else 0)
        if shape != (rows, cols):
            return 'has shape {}x{}, expected {}x{}'.format(shape[0], shape[1], rows, cols)
        for i, row in enumerate(m):
            for j, v in enumerate(row):
                if not is_number(v):
                    return 'entry [{}][{}] is {!r}, not a number'.format(i, j, v)
                if not math.isfinite(v):
                    return 'entry [{}][{}] is {!r}, not finite'.format(i, j, v)
        return None
    return check


class Fields(object):
    """The fields of one file: raises ``error('<source>: field <name> <problem>')``."""

    def __init__(self, source, error):
        self.source = source
        self.error = error

    def fail(self, field, problem):
        raise self.error(message(self.source, field, problem))

    def check(self, field, value, checker):
        """value, if checker finds no problem with it."""
        problem = checker(value)
        if problem:
            self.fail(field, problem)
        return value

    def number(self, field, value, **bounds):
        """float(value) after number(**bounds) accepted it."""
        return float(self.check(field, value, number(**bounds)))

    def require(self, doc, names, prefix=''):
        """Every name is a key of doc."""
        for name in names:
            if name not in doc:
                self.fail(prefix + name, 'is missing')

    def known(self, doc, names, prefix=''):
        """Every key of doc is one of names (the first unknown one, sorted, is named)."""
        unknown = sorted(set(doc) - set(names))
        if unknown:
            self.fail(prefix + unknown[0], 'is unknown')


def read_json(path, error):
    """(parsed document, raw bytes) of a UTF-8 JSON file; error('<path>: ...') if it cannot be
    read or is not JSON."""
    try:
        with open(path, 'rb') as f:
            data = f.read()
    except OSError as e:
        raise error('{}: cannot read: {}'.format(path, e.strerror or e))
    try:
        return json.loads(data.decode('utf-8')), data
    except (ValueError, UnicodeError) as e:
        raise error('{}: not valid JSON: {}'.format(path, e))


def read_object(path, error):
    """The JSON object in the file at path (see read_json)."""
    doc = read_json(path, error)[0]
    if not isinstance(doc, dict):
        raise error('{}: must be a JSON object'.format(path))
    return doc
