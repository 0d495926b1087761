"""The robot-side code (tipbot_fw/, ev3/) must run on the brick's Python 3.5.3.

- vermin (`-t=3.5-`) finds every construct, module, function and keyword argument that needs a
  Python newer than 3.5 (f-strings, variable annotations, `secrets`, `random.choices`, ...).
- An AST scan refuses host-only imports (scipy, sympy, matplotlib, control, hostsim, ...).
Neither can see behaviour that changed without a new name (dict ordering is only guaranteed from
3.7; `json.loads` of bytes needs 3.6): the tests that run the firmware cover those.
"""
import ast
import os
import subprocess
import sys

import pytest

from robot_side import REPO, ROBOT_DIRS, robot_python_files
FORBIDDEN = ("scipy", "sympy", "matplotlib", "control", "hostsim", "tqdm", "mpmath", "pandas",
             "dataclasses", "typing_extensions")
VERMIN_ARGS = ["--no-tips", "--violations", "-t=3.5-", "--eval-annotations"]


def run_vermin(paths):
    # vermin has no __main__ module: call its console entry point with this interpreter
    cmd = [sys.executable, "-c", "import sys, vermin; sys.argv[0] = 'vermin'; sys.exit(vermin.main())"]
    proc = subprocess.run(cmd + VERMIN_ARGS + list(paths), cwd=REPO,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
    return proc.returncode, proc.stdout


def forbidden_imports(source, filename="<string>"):
    """[(lineno, module)] of the imports of host-only modules in `source`."""
    bad = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            mods = [node.module]
        elif isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) \
                in ("__import__", "import_module") and node.args and isinstance(node.args[0], ast.Constant):
            mods = [str(node.args[0].value)]
        else:
            continue
        bad += [(node.lineno, m) for m in mods if m.split(".")[0] in FORBIDDEN]
    return bad


def test_vermin_catches_py36_code(tmp_path):
    # the exact vermin invocation must be able to fail
    f = tmp_path / "new.py"
    f.write_text("x: int = 1\nprint(f'{x}')\n")
    rc, out = run_vermin([str(f)])
    assert rc != 0 and "f-strings require !2, 3.6" in out, out


def test_robot_code_needs_at_most_python_3_5():
    paths = [os.path.relpath(p, REPO) for p in robot_python_files()]
    if not paths:
        pytest.skip("no robot-side python files yet")
    rc, out = run_vermin(paths)
    assert rc == 0, "vermin {} {}:\n{}".format(" ".join(VERMIN_ARGS), " ".join(ROBOT_DIRS), out)


def test_forbidden_import_checker():
    src = ("import numpy as np\nimport scipy.linalg\nfrom hostsim import plant\n"
           "from sympy import Matrix as M\nimport os, matplotlib.pyplot as plt\n"
           "from . import gains\nimport importlib\nm = importlib.import_module('control')\n"
           "import controller\n")
    assert forbidden_imports(src) == [(2, "scipy.linalg"), (3, "hostsim"), (4, "sympy"),
                                      (5, "matplotlib.pyplot"), (8, "control")]


def test_robot_code_has_no_host_only_imports():
    bad = []
    for path in robot_python_files():
        with open(path, "rb") as f:
            src = f.read()
        for line, mod in forbidden_imports(src, path):
            bad.append("{}:{}: imports {} (host-only)".format(os.path.relpath(path, REPO), line, mod))
    assert not bad, "\n".join(bad)


def test_robot_code_is_utf8_and_parses():
    # Python 3.5 reads sources as UTF-8; a BOM or another encoding fails there first.
    for path in robot_python_files():
        with open(path, "rb") as f:
            raw = f.read()
        assert not raw.startswith(b"\xef\xbb\xbf"), path + ": BOM"
        raw.decode("utf-8")
        ast.parse(raw, path)
