"""numpy without the subpackages a run never uses: ``import_numpy()`` imports numpy with its
``random``, ``fft``, ``polynomial``, ``ma`` and ``ctypeslib`` left out until something uses them.

``import numpy`` loads every subpackage its ``__init__`` names (``from . import random`` ...),
whether used or not: on the virtual brick's numpy 1.24 the five above are about 6 MB of a run's
memory (numpy.random's extension modules, and through its ``secrets`` the OpenSSL library;
numpy.ma's and numpy.polynomial's classes), a fifth of the controller's (docs/benchmarks.md,
"Memory"). The firmware uses none of them (its arithmetic is numpy's core and one
``linalg.eigvals``; tests/test_lean_numpy.py checks its sources for them).

How: while numpy's ``__init__`` runs, a finder at the front of ``sys.meta_path`` answers for
those five names with a placeholder module (a ModuleType whose attribute look-up imports the
real subpackage: nothing breaks if something does use one later, it is only loaded then). In
numpy 1.12 (the brick's) and 1.24 (the virtual brick's) nothing else imports them during
numpy's import (their sources: ``from . import fft`` ... in numpy/__init__.py only); should a
numpy do so, the placeholder imports the real one then. After the import the finder and the
placeholders' ``sys.modules`` entries are removed, so ``import numpy.random`` works as always
(and puts the real module in ``numpy.random``).

Standard library only; for the controller's command line (tipbot_fw.__main__), before anything
imports numpy; the host and the tests import numpy as usual.
"""
import importlib
import sys
import types

DEFERRED = ('numpy.random', 'numpy.fft', 'numpy.polynomial', 'numpy.ma', 'numpy.ctypeslib')


class Deferred(types.ModuleType):
    """Stands for a numpy subpackage not loaded: once numpy's import is over (``ready``), the
    first attribute looked up on it imports the real one (which then replaces it in numpy's
    namespace) and answers from it. Before that, and for the import machinery's own questions
    (``__file__``, ``__path__`` ...), it has no attributes."""

    ready = False

    def __getattr__(self, name):
        if not self.ready or name.startswith('__'):
            raise AttributeError('{} has no attribute {} (not loaded: tipbot_fw.lean_numpy)'.format(
                self.__name__, name))
        return getattr(importlib.import_module(self.__name__), name)


class _Finder(object):
    """Answers for the DEFERRED names with a Deferred module (only while numpy is imported)."""

    def find_spec(self, name, path=None, target=None):
        if name not in DEFERRED:
            return None
        from importlib.machinery import ModuleSpec
        return ModuleSpec(name, self)

    # the loader's half (Python 3.4+: create_module, exec_module)
    def create_module(self, spec):
        return Deferred(spec.name)

    def exec_module(self, module):
        pass


def import_numpy(may_retry=lambda: True):
    """numpy, imported with the DEFERRED subpackages left out (or as it is, if already
    imported). -> the numpy module.

    Fail-safe: should a numpy's own import need one of them after all (a numpy other than the
    ones whose sources were read), that import fails on the placeholder; then numpy is imported
    again, whole, as a plain ``import numpy`` would: a run costs its memory, never its start.
    ``may_retry()`` False (a signal, which numpy's C extensions turn into an ImportError, ended
    the first try: tipbot_fw.__main__) re-raises instead."""
    if 'numpy' in sys.modules:
        return sys.modules['numpy']
    finder = _Finder()
    sys.meta_path.insert(0, finder)
    try:
        import numpy
        return numpy
    except Exception:
        if not may_retry():
            raise
    finally:
        sys.meta_path.remove(finder)
        for name in DEFERRED:
            if isinstance(sys.modules.get(name), Deferred):
                sys.modules.pop(name).ready = True
    for name in [m for m in sys.modules if m == 'numpy' or m.startswith('numpy.')]:
        del sys.modules[name]       # what the first try left half made
    import numpy
    return numpy
