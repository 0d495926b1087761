"""The rooms of hostsim and of the firmware: the subpackages import one way only, the top level
stays small, and the docs' layout tables list every module.

hostsim: model (robot model, gain design) <- world (plant, sensors, fake EV3, the lock-step
worlds) <- sim (scenarios, simulators, runner) <- studies (Monte Carlo, region of attraction,
report); logs (replay, identification) needs only the model.
tipbot_fw: io and guard import no other room, cores only guard, record and drive only cores;
every room may import the top-level foundation (vocabulary, fields, console, config), which
imports no room; the rest of the top level is the application.
Imports are read with ast, function-level ones included, so a late import cannot hide an arrow
pointing the wrong way.
"""
import ast
import os
import re

import pytest

from conftest import REPO

HOSTSIM = os.path.join(REPO, "hostsim")
FIRMWARE = os.path.join(REPO, "tipbot_fw")
# What each subpackage may import besides itself, the top-level modules and tipbot_fw.
ALLOWED = {
    "model": set(),
    "world": {"model"},
    "sim": {"model", "world"},
    "studies": {"model", "world", "sim"},
    "logs": {"model"},
}
TOP_LEVEL = {"__init__", "__main__", "errors", "paths"}
# The firmware's rooms: what each may import besides itself and the foundation
FW_ALLOWED = {
    "io": set(),
    "guard": set(),
    "cores": {"guard"},
    "record": {"cores"},
    "drive": {"cores"},
}
FW_FOUNDATION = {"vocabulary", "fields", "console", "config"}


def hostsim_imports(path, root=REPO, top="hostsim"):
    """[(line, 'hostsim.x.y')] of every import in the file (relative ones resolved from its
    place under root); of another top package than hostsim with `top`."""
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
            if module == top or top == "tipbot_fw" and module.count(".") == 1 and module.split(".")[1] in FW_ALLOWED:
                # from hostsim import x, from tipbot_fw.cores import x: x is the module imported
                found += [(node.lineno, module + "." + a.name) for a in node.names]
            else:
                found.append((node.lineno, module))
    return [(line, m) for line, m in found if m == top or m.startswith(top + ".")]


def modules(top=HOSTSIM):
    for dirpath, dirnames, filenames in os.walk(top):
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


def fw_room(module):
    """'cores' for tipbot_fw.cores.x (or tipbot_fw.cores), None for a top-level module."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in FW_ALLOWED else None


def test_firmware_rooms_import_only_lower_ones():
    bad = []
    for path in modules(FIRMWARE):
        here = os.path.relpath(path, REPO)[:-3].replace(os.sep, ".")
        mine = fw_room(here)
        top = here.split(".")[1] if mine is None else None
        if mine is None and top not in FW_FOUNDATION:
            continue        # the application may import anything
        for line, target in hostsim_imports(path, top="tipbot_fw"):
            other = fw_room(target)
            name = target.split(".")[1] if target.count(".") else None
            if other is None:
                if name is not None and name not in FW_FOUNDATION and name != "__init__":
                    bad.append("%s:%d imports the application's %s (a room imports only the foundation %s)"
                               % (os.path.relpath(path, REPO), line, target, ", ".join(sorted(FW_FOUNDATION))))
            elif mine is None:
                bad.append("%s:%d imports %s (the foundation imports no room)" % (os.path.relpath(path, REPO), line,
                                                                                 target))
            elif other != mine and other not in FW_ALLOWED[mine]:
                bad.append("%s:%d imports %s (%s may import only %s)" % (
                    os.path.relpath(path, REPO), line, target, mine, ", ".join(sorted(FW_ALLOWED[mine])) or "itself"))
    assert not bad, "\n".join(bad)


def test_the_firmware_has_its_rooms_and_its_foundation():
    packages = {n for n in os.listdir(FIRMWARE) if os.path.isfile(os.path.join(FIRMWARE, n, "__init__.py"))}
    assert packages == set(FW_ALLOWED)
    assert all(os.path.isfile(os.path.join(FIRMWARE, m + ".py")) for m in FW_FOUNDATION)


@pytest.mark.parametrize("source, mine, expected", [
    ("from tipbot_fw.cores import kalman\n", "io", ["tipbot_fw.cores.kalman"]),
    ("def f():\n    from tipbot_fw.record.logfile import read_log\n", "cores", ["tipbot_fw.record.logfile"]),
    ("from tipbot_fw import gains\n", "cores", ["tipbot_fw.gains"]),
])
def test_a_firmware_arrow_the_wrong_way_is_found(tmp_path, source, mine, expected):
    d = tmp_path / "tipbot_fw" / mine
    d.mkdir(parents=True)
    p = d / "x.py"
    p.write_text(source)
    found = [m for _, m in hostsim_imports(str(p), root=str(tmp_path), top="tipbot_fw")]
    assert found == expected
    other = fw_room(found[0])
    assert (other is None and found[0].split(".")[1] not in FW_FOUNDATION) or other not in FW_ALLOWED[mine]


# A docs table of a package's layout: | package | what lives there | modules |; each row a
# subpackage (`hostsim.model`) or the top level, its modules in backticks in the last column
LAYOUT_HEADER = "| package | what lives there | modules |"


def layout_tables(text):
    """[{package or 'top level': set of backticked names in its modules column}] of a page."""
    tables, current = [], None
    for line in text.splitlines():
        if line.strip() == LAYOUT_HEADER:
            current = {}
            tables.append(current)
        elif current is not None and line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if set(cells[0]) <= set("-"):
                continue
            current[cells[0].strip("`")] = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_.]*)`", cells[-1]))
        else:
            current = None
    return tables


def package_modules(package):
    d = os.path.join(REPO, *package.split("."))
    return {n[:-3] for n in os.listdir(d) if n.endswith(".py") and n != "__init__.py"}


def test_every_layout_table_in_the_docs_lists_every_module():
    seen, missing = 0, []
    for page in sorted(os.listdir(os.path.join(REPO, "docs"))):
        if not page.endswith(".md"):
            continue
        with open(os.path.join(REPO, "docs", page)) as f:
            tables = layout_tables(f.read())
        for table in tables:
            roots = {p.split(".")[0] for p in table if p != "top level"}
            assert len(roots) == 1, "%s: a layout table of one package: %s" % (page, sorted(table))
            root = roots.pop()
            subs = {n for n in os.listdir(os.path.join(REPO, root))
                    if os.path.isfile(os.path.join(REPO, root, n, "__init__.py"))}
            assert set(table) == {root + "." + s for s in subs} | {"top level"}, page
            for row, listed in table.items():
                package = root if row == "top level" else row
                wanted = package_modules(package) | ({"__init__"} & listed if row == "top level" else set())
                missing += ["%s: %s does not list %s" % (page, row, m) for m in sorted(wanted - listed)]
            seen += 1
    assert seen >= 2        # hostsim's and the firmware's, in docs/architecture.md
    assert not missing, "\n".join(missing)


def test_a_layout_table_is_read_row_by_row():
    text = LAYOUT_HEADER + "\n|---|---|---|\n| `pkg.a` | x | `m1` (the `Thing`), `m2` |\n| top level | | `main` |\n\nafter"
    assert layout_tables(text) == [{"pkg.a": {"m1", "Thing", "m2"}, "top level": {"main"}}]


def module_graph(top_dir, top):
    """{module: set of the package's modules it imports} (function-level imports included;
    `from a.b import c` counts as a.b.c where c is a module)."""
    names = {os.path.relpath(p, REPO)[:-3].replace(os.sep, ".").replace(".__init__", "") for p in modules(top_dir)}
    graph = {}
    for path in modules(top_dir):
        here = os.path.relpath(path, REPO)[:-3].replace(os.sep, ".").replace(".__init__", "")
        with open(path) as f:
            tree = ast.parse(f.read(), path)
        out = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                out |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                out |= {node.module + "." + a.name if node.module + "." + a.name in names else node.module
                        for a in node.names}
        graph[here] = {m for m in out if m in names and m != here and not here.startswith(m + ".")}
    return graph


def cycles(graph):
    """Every import circle of the graph, as a list of modules (one per circle found)."""
    found, state = [], {}

    def visit(m, stack):
        state[m] = 1
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                found.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n, stack + [n])
        state[m] = 2
    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return found


@pytest.mark.parametrize("top", ["hostsim", "tipbot_fw"])
def test_no_import_circle(top):
    found = cycles(module_graph(os.path.join(REPO, top), top))
    assert not found, "\n".join(" -> ".join(c) for c in found)


def test_an_import_circle_is_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
