"""tipbot_fw.lean_numpy: numpy imported without the subpackages a run never uses, which load on
first use; and a run's start that keeps out of memory what it does not use (docs/benchmarks.md,
"Memory")."""
import os
import re
import subprocess
import sys
import textwrap

from conftest import REPO
from robot_side import robot_python_files

# A numpy whose __init__ names its subpackages as numpy 1.12's and 1.24's do (``from . import
# random`` ...): each subpackage records in numpy.LOADED that it ran.
FAKE_NUMPY = {
    "__init__.py": "LOADED = []\nfrom . import core\nfrom . import fft\nfrom . import polynomial\n"
                   "from . import random\nfrom . import ctypeslib\nfrom . import ma\n"
                   "__all__ = ['fft', 'random', 'ctypeslib', 'ma']\n",
    "core.py": "import numpy\nnumpy.LOADED.append('core')\n",
    "fft/__init__.py": "import numpy\nnumpy.LOADED.append('fft')\nfft = 'the fft'\n",
    "polynomial/__init__.py": "import numpy\nnumpy.LOADED.append('polynomial')\n",
    "random/__init__.py": "import numpy\nnumpy.LOADED.append('random')\nfrom .mtrand import rand\n",
    "random/mtrand.py": "def rand():\n    return 0.25\n",
    "ctypeslib.py": "import numpy\nnumpy.LOADED.append('ctypeslib')\n",
    "ma/__init__.py": "import numpy\nnumpy.LOADED.append('ma')\nmasked = 'masked'\n",
}


def _run(code, path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([path, REPO]))
    p = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=path,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return p.stdout


def test_the_subpackages_a_run_does_not_use_load_only_when_used(tmp_path):
    for name, text in FAKE_NUMPY.items():
        path = tmp_path / "numpy" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    out = _run("""
        import sys
        from tipbot_fw.lean_numpy import import_numpy
        np = import_numpy()
        print(np.LOADED, sorted(m for m in sys.modules if m.startswith('numpy.')))
        print(np.random.rand(), np.LOADED)             # first use: the real one, loaded now
        print(type(np.random).__name__, sys.modules['numpy.random'] is np.random)
        import numpy.ma
        print(numpy.ma.masked, np.ma is sys.modules['numpy.ma'], np.LOADED)
        print(import_numpy() is np, 'fft' in np.__all__)
        """, str(tmp_path))
    assert out.splitlines() == [
        "['core'] ['numpy.core']",
        "0.25 ['core', 'random']",
        "module True",
        "masked True ['core', 'random', 'ma']",
        "True True"]


def test_a_numpy_subpackage_that_fails_to_import_later_says_so(tmp_path):
    for name, text in FAKE_NUMPY.items():
        path = tmp_path / "numpy" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text.replace("masked = 'masked'", "raise ImportError('no ma here')"))
    out = _run("""
        from tipbot_fw.lean_numpy import import_numpy
        np = import_numpy()
        try:
            np.ma.masked
        except ImportError as e:
            print('ImportError', e)
        """, str(tmp_path))
    assert out.strip() == "ImportError no ma here"


def _numpy_that_needs_random_while_importing(tmp_path):
    # a numpy other than 1.12's and 1.24's: its core uses numpy.random while numpy imports
    for name, text in FAKE_NUMPY.items():
        path = tmp_path / "numpy" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text.replace("numpy.LOADED.append('core')\n",
                                     "numpy.LOADED.append('core')\nfrom numpy.random import rand\n"))


def test_a_numpy_whose_own_import_needs_a_left_out_subpackage_is_imported_whole(tmp_path):
    # the placeholder fails that import; the run still starts, numpy imported as it is
    _numpy_that_needs_random_while_importing(tmp_path)
    out = _run("""
        import sys
        from tipbot_fw.lean_numpy import Deferred, _Finder, import_numpy
        np = import_numpy()
        print(np.LOADED, np.random.rand(), isinstance(np.random, Deferred))
        print(any(isinstance(f, _Finder) for f in sys.meta_path))
        """, str(tmp_path))
    assert out.splitlines() == ["['core', 'random', 'fft', 'polynomial', 'ctypeslib', 'ma'] 0.25 False", "False"]


def test_no_second_try_when_a_signal_ended_the_first(tmp_path):
    _numpy_that_needs_random_while_importing(tmp_path)
    out = _run("""
        from tipbot_fw.lean_numpy import import_numpy
        try:
            import_numpy(may_retry=lambda: False)
        except ImportError as e:
            print('ImportError')
        """, str(tmp_path))
    assert out.strip() == "ImportError"


def test_the_firmware_uses_none_of_the_subpackages_it_leaves_out():
    """What lean_numpy leaves out would load on first use: that would be a run's memory again."""
    pattern = re.compile(r"\b(np|numpy)\.(random|fft|polynomial|ma|ctypeslib)\b"
                         r"|from numpy import .*\b(random|fft|polynomial|ma|ctypeslib)\b")
    uses = ["{}:{}".format(os.path.relpath(path, REPO), i + 1)
            for path in robot_python_files() if not path.endswith("lean_numpy.py")
            for i, line in enumerate(open(path, encoding="utf-8")) if pattern.search(line.split("#")[0])]
    assert uses == []


def test_a_run_start_keeps_out_what_a_run_does_not_use():
    """The controller's imports up to its loop, as python3 -m tipbot_fw run: not the experiments,
    identify, the bench, the socket modules (telemetry, remote) or OpenSSL's hash library."""
    out = _run("""
        import sys
        from tipbot_fw.lean_numpy import import_numpy
        import_numpy()
        from tipbot_fw import cli
        from tipbot_fw.gains import load_gains
        cli._parser(['run', '--gains', 'gains/physical.json']).parse_args(['run', '--gains', 'g'])
        g = load_gains('gains/physical.json')
        import tipbot_fw.session, tipbot_fw.io.ev3dev
        print(len(g.sha256), sorted(m for m in ('tipbot_fw.experiments', 'tipbot_fw.identify', 'tipbot_fw.bench',
              'socket', '_hashlib', 'numpy.random', 'numpy.ma') if m in sys.modules))
        cli._parser(['fall-test', '--help'])
        print(sorted(m for m in ('tipbot_fw.experiments', 'tipbot_fw.identify') if m in sys.modules))
        """, REPO)
    assert out.splitlines() == ["64 []", "['tipbot_fw.experiments', 'tipbot_fw.identify']"]
