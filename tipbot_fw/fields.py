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


def printable(text):
    """text with what would break a one-line message (newlines, control characters) escaped."""
    return ''.join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))


def message(source, field, problem):
    """The one format of a bad field (one line, whatever the field's name holds)."""
    return '{}: field {} {}'.format(source, printable(field), printable(problem))


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


def _instance_of(kind, what):
    """Checker of a value of JSON type `kind` (a Python type), described as `what`."""
    def check(v):
        if not isinstance(v, kind):
            return 'must be {}, got {!r}'.format(what, v)
        return None
    return check


string = _instance_of(str, 'a string')
boolean = _instance_of(bool, 'true or false')
obj = _instance_of(dict, 'an object')
array = _instance_of(list, 'a list')


def nonempty_string(v):
    if not isinstance(v, str) or not v:
        return 'must be a non-empty string, got {!r}'.format(v)
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
    """The fields of one file: raises ``error('<source>: field <prefix><name> <problem>')``
    (prefix: where these fields sit in the file, when another file's format is nested in it)."""

    def __init__(self, source, error, prefix=''):
        self.source = source
        self.error = error
        self.prefix = prefix

    def fail(self, field, problem):
        raise self.error(message(self.source, self.prefix + field, problem))

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


class JsonProblem(ValueError):
    """A JSON text that cannot be taken as it is; the message says where (field or position)."""


class _Huge(object):
    """A number JSON can write and a float cannot hold (1e400, an integer of 400 digits)."""

    def __init__(self, text):
        self.text = text


MAX_DEPTH = 32          # nesting of objects and lists: deeper is no file of ours
MAX_FILE_BYTES = 8 * 1024 * 1024
_MAX_INT_DIGITS = 30


def _parse_int(text):
    digits = text.lstrip('-')
    if len(digits) > _MAX_INT_DIGITS:
        return _Huge(text if len(text) < 24 else text[:12] + '...({} digits)'.format(len(digits)))
    return int(text)


def _parse_float(text):
    v = float(text)
    if math.isinf(v):
        return _Huge(text)
    return v


class _NotJson(_Huge):
    """NaN, Infinity or -Infinity: Python's json reads them, JSON has no such numbers."""


def _parse_constant(name):
    return _NotJson(name)


def _pairs(pairs):
    doc = {}
    for key, value in pairs:
        if key in doc:
            raise JsonProblem('key {!r} appears twice in one object'.format(key))
        doc[key] = value
    return doc


def _check_values(doc):
    """The first value JSON parsed that no field can take: (dotted path, problem), or None."""
    stack = [('', doc, 0)]
    while stack:
        path, v, depth = stack.pop()
        if depth > MAX_DEPTH:
            return path, 'is nested deeper than {} levels'.format(MAX_DEPTH)
        if isinstance(v, _NotJson):
            return path, 'is {}, not a finite number (JSON has none)'.format(v.text)
        if isinstance(v, _Huge):
            return path, 'is {}, beyond the range of a number'.format(v.text)
        if isinstance(v, dict):
            stack.extend(((path + '.' if path else '') + str(k), x, depth + 1) for k, x in sorted(v.items(), reverse=True))
        elif isinstance(v, list):
            stack.extend(('{}[{}]'.format(path, i), x, depth + 1) for i, x in reversed(list(enumerate(v))))
    return None


def loads(data):
    """Parse UTF-8 JSON bytes strictly -> the document. JsonProblem, one line, for anything a
    reader cannot take: invalid UTF-8 or JSON, NaN or Infinity, duplicate keys, numbers no float
    holds (1e400, 10**400 written out), nesting deeper than MAX_DEPTH."""
    try:
        text = data.decode('utf-8-sig')     # a byte-order mark (Windows Notepad's UTF-8) is no error
    except UnicodeError as e:
        raise JsonProblem('is not UTF-8 text: {}'.format(e))
    try:
        doc = json.loads(text, parse_int=_parse_int, parse_float=_parse_float,
                         parse_constant=_parse_constant, object_pairs_hook=_pairs)
    except JsonProblem:
        raise
    except RecursionError:
        raise JsonProblem('is nested deeper than {} levels'.format(MAX_DEPTH))
    except (ValueError, TypeError, OverflowError, RuntimeError) as e:
        raise JsonProblem('not valid JSON: {}'.format(str(e).splitlines()[0] if str(e) else type(e).__name__))
    bad = _check_values(doc)
    if bad:
        where, problem = bad
        raise JsonProblem('field {} {}'.format(printable(where), problem) if where else problem)
    return doc


def read_json(path, error):
    """(parsed document, raw bytes) of a UTF-8 JSON file; error('<path>: ...'), one line, if it
    cannot be read or parsed (see loads)."""
    try:
        with open(path, 'rb') as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as e:
        raise error('{}: cannot read: {}'.format(path, e.strerror or e))
    except (TypeError, ValueError) as e:    # a path that is no path (an embedded NUL)
        raise error('{!r}: cannot read: {}'.format(path, e))
    if len(data) > MAX_FILE_BYTES:
        raise error('{}: larger than {} MB: not one of our files'.format(path, MAX_FILE_BYTES // (1024 * 1024)))
    try:
        return loads(data), data
    except JsonProblem as e:
        raise error('{}: {}'.format(path, e))


def read_object(path, error):
    """The JSON object in the file at path (see read_json)."""
    doc = read_json(path, error)[0]
    if not isinstance(doc, dict):
        raise error('{}: must be a JSON object'.format(path))
    return doc
