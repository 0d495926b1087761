"""Errors raised by the host-side tools.

Each carries a message that names the file, field or matrix at fault, so a command
line tool can print it as one line and exit non-zero. Files are checked field by field
with tipbot_fw.fields, so every bad field reads ``<file>: field <dotted.name> <problem>``.
"""


class TipbotError(Exception):
    """Base class of the host tools' expected failures (bad input, impossible design)."""


class ParameterError(TipbotError):
    """A robot parameters file is missing a field or holds an invalid value."""


class DesignError(TipbotError):
    """A gain design cannot be carried out (uncontrollable, singular weight, ...)."""
