"""Every numpy name the robot-side code uses must exist in numpy 1.12 (the brick's numpy).

Statically collects each `np.X`, `numpy.X`, `np.linalg.X`, `np.random.X`, ... (whatever name
numpy or a numpy subpackage is imported as, and `from numpy[.sub] import X`) in tipbot_fw/ and
ev3/, and checks it against tests/data/numpy_1_12_api.txt, which tools/gen-numpy112-api reads off
the real numpy 1.12.1. Names must also exist in the host's numpy, which runs the same code in the
simulator and the tests. Methods of arrays (`a.dot(b)`) and keyword arguments added after 1.12
(`np.linalg.norm(..., keepdims=True)` is 1.10: fine) cannot be seen by this check.
"""
import ast
import os

import numpy
import pytest

from robot_side import REPO, robot_python_files

API_FILE = os.path.join(REPO, "tests", "data", "numpy_1_12_api.txt")


def load_api():
    with open(API_FILE) as f:
        return frozenset(line.strip() for line in f if line.strip() and not line.startswith("#"))


API = load_api()
SUBPACKAGES = frozenset(name.split(".")[0] for name in API if "." in name)


def _chain(node):
    """`a.b.c` -> ['a', 'b', 'c'] for a chain of attributes ending in a Name, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return parts[::-1]
    return None


def numpy_uses(source, filename="<string>"):
    """Returns [(lineno, 'name' or 'sub.name')] for every numpy attribute `source` uses."""
    tree = ast.parse(source, filename)
    aliases = {}  # local name -> numpy path prefix: '' for numpy itself, 'linalg' for np.linalg
    uses = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] != "numpy":
                    continue
                if a.asname:
                    aliases[a.asname] = ".".join(parts[1:])
                else:
                    aliases["numpy"] = ""
                if len(parts) > 1:
                    uses.append((node.lineno, ".".join(parts[1:])))
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "numpy":
            prefix = ".".join(node.module.split(".")[1:])
            if prefix:
                uses.append((node.lineno, prefix))
            for a in node.names:
                full = prefix + "." + a.name if prefix else a.name
                uses.append((node.lineno, full))
                if full in SUBPACKAGES:
                    aliases[a.asname or a.name] = full
    inner = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or id(node) in inner:
            continue  # only whole chains: np.linalg.norm, not also np.linalg
        chain = _chain(node)
        if not chain or chain[0] not in aliases:
            continue
        path = ([aliases[chain[0]]] if aliases[chain[0]] else []) + chain[1:]
        # keep 'name', or 'sub.name' when the first component is a subpackage
        name = ".".join(path[:2]) if path[0] in SUBPACKAGES and len(path) > 1 else path[0]
        uses.append((node.lineno, name))
    return sorted(set(uses))


def not_in_api(uses):
    return [(line, name) for line, name in uses if name not in API]


def host_has(name):
    obj = numpy
    for part in name.split("."):
        if not hasattr(obj, part):
            return False
        obj = getattr(obj, part)
    return True


# --- the list itself and the checker can tell wrong from right ---------------------------------

def test_api_list_is_numpy_1_12():
    # present in 1.12
    for name in ("array", "dot", "matmul", "flip", "stack", "einsum", "linalg.norm", "linalg.solve",
                 "random.RandomState", "random.seed", "float64", "pi", "newaxis", "__version__"):
        assert name in API, name
    # added in 1.13 or later, or not on the brick's ARM, or removed from the host's numpy
    for name in ("isin", "block", "heaviside", "divmod", "unique_counts", "float128", "float",
                 "int", "bool", "linalg.linalg", "random.default_rng", "core"):
        assert name not in API, name


def test_checker_flags_post_1_12_names():
    src = ("import numpy as np\nimport numpy.linalg as la\nfrom numpy import isin, linalg\n"
           "from numpy.random import default_rng\n"
           "def f(a, b):\n    return np.isin(a, b), np.block([a]), la.multi_dot([a, b]), linalg.norm(a)\n"
           "x = np.linalg.norm(np.array([1.0]), ord=2) + np.random.rand()\n"
           "y = np.linalg.matrix_transpose\n")
    uses = numpy_uses(src)
    assert not_in_api(uses) == [(3, "isin"), (4, "random.default_rng"), (6, "block"), (6, "isin"),
                                (8, "linalg.matrix_transpose")]
    names = {n for _, n in uses}
    assert {"linalg", "linalg.multi_dot", "linalg.norm", "array", "random.rand"} <= names


def test_checker_handles_plain_import_numpy():
    uses = numpy_uses("import numpy\nnumpy.random.seed(0)\nz = numpy.zeros((2, 2)).T\n")
    assert uses == [(2, "random.seed"), (3, "zeros")]


# --- the robot-side code ---------------------------------------------------------------------

def test_robot_code_uses_only_numpy_1_12_names():
    files = robot_python_files()
    bad = []
    for path in files:
        with open(path) as f:
            for line, name in not_in_api(numpy_uses(f.read(), path)):
                bad.append("{}:{}: np.{} is not in numpy 1.12".format(os.path.relpath(path, REPO), line, name))
    assert not bad, "\n".join(bad + ["(allow-list: tests/data/numpy_1_12_api.txt)"])


def test_robot_numpy_names_exist_on_host_numpy():
    bad = []
    for path in robot_python_files():
        with open(path) as f:
            for line, name in numpy_uses(f.read(), path):
                if not host_has(name):
                    bad.append("{}:{}: np.{} is not in the host's numpy {}".format(
                        os.path.relpath(path, REPO), line, name, numpy.__version__))
    assert not bad, "\n".join(bad)


@pytest.mark.skipif(not os.path.isdir(os.path.join(REPO, "tipbot_fw")), reason="no tipbot_fw yet")
def test_robot_code_is_scanned():
    files = robot_python_files()
    assert any(p.endswith(os.path.join("tipbot_fw", "__init__.py")) for p in files)
