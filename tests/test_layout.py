"""hostsim's rooms: the subpackages import one way only, and the top level stays small.

model (robot model, gain design) <- world (plant, sensors, fake EV3) <- sim (scenarios,
simulators, runner) <- studies (Monte Carlo, region of attraction, report); logs (replay,
identification) needs only the model. Imports are read with ast, function-level ones
included, so a late import cannot hide an arrow pointing the wrong way.
"""
import ast
import os

import pytest

from conftest import REPO

HOSTSIM = os.path.join(REPO, "hostsim")
# What each subpackage may import besides itself, the top-level modules and tipbot_fw.
ALLOWED = {
    "model": set(),
    "world": {"model"},
    "sim": {"model", "world"},
    "studies": {"model", "world", "sim"},
    "logs": {"model"},
}
TOP_LEVEL = {"__init__", "__main__", "errors", "paths"}


def hostsim_imports(path, root=REPO):
    """[(line, 'hostsim.x.y')] of every import in the file (relative ones resolved from its
    place under root)."""
    with open(path) as f:
        tree = ast.parse(f.read(), path)
    package = os.path.relpath(os.path.dirname(path), root).replace(os.sep, ".")
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                module = base + ("." + node.module if node.module else "")
            else:
                module = node.module
            if module == "hostsim":     # from hostsim import x: x is the module imported
                found += [(node.lineno, "hostsim." + a.name) for a in node.names]
            else:
                found.append((node.lineno, module))
    return [(line, m) for line, m in found if m == "hostsim" or m.startswith("hostsim.")]


def modules():
    for dirpath, dirnames, filenames in os.walk(HOSTSIM):
        dirnames[:] = [d for d in dirnames if d != "__pycache__"]
        for name in filenames:
            if name.endswith(".py"):
                yield os.path.join(dirpath, name)


def room(module):
    """'model' for hostsim.model.x, None for a top-level module."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in ALLOWED) else None


def test_subpackages_import_only_lower_ones():
    bad = []
    for path in modules():
        here = os.path.relpath(path, REPO)[:-3].replace(os.sep, ".")
        mine = room(here) if here.count(".") > 1 else None
        if mine is None:
            continue
        for line, target in hostsim_imports(path):
            other = room(target)
            if other is not None and other != mine and other not in ALLOWED[mine]:
                bad.append("%s:%d imports %s (%s may import only %s)"
                           % (os.path.relpath(path, REPO), line, target, mine, ", ".join(sorted(ALLOWED[mine])) or "itself"))
    assert not bad, "\n".join(bad)


def test_top_level_holds_only_the_entry_points():
    entries = {n[:-3] for n in os.listdir(HOSTSIM) if n.endswith(".py")}
    packages = {n for n in os.listdir(HOSTSIM) if os.path.isfile(os.path.join(HOSTSIM, n, "__init__.py"))}
    assert entries == TOP_LEVEL
    assert packages == set(ALLOWED)


@pytest.mark.parametrize("source, expected", [
    ("from hostsim.sim import firmware_run\n", ["hostsim.sim"]),
    ("def f():\n    from hostsim.studies.plots import x\n", ["hostsim.studies.plots"]),
    ("from hostsim import paths\n", ["hostsim.paths"]),
    ("from ..sim.metrics import y\n", ["hostsim.sim.metrics"]),
])
def test_imports_are_found_wherever_they_are(tmp_path, source, expected):
    # A file laid where hostsim/model/x.py would be: relative imports resolve from there.
    d = tmp_path / "hostsim" / "model"
    d.mkdir(parents=True)
    p = d / "x.py"
    p.write_text(source)
    assert [m for _, m in hostsim_imports(str(p), root=str(tmp_path))] == expected
