"""tools/tick-cost: instructions per tick = (count(N ticks) - count(0 ticks)) / N."""
import os
import subprocess
import sys

import pytest

from conftest import REPO

TICK_COST = os.path.join(REPO, "tools", "tick-cost")
INSNS = os.path.join(REPO, "tools", "insns")

FAKE_INSNS = '''\
import sys
args = sys.argv[1:]
if "--fail" in args:
    print("boom", file=sys.stderr)
    sys.exit(1)
n = int(args[args.index("--ticks") + 1])
print("insns: %d" % (40000000 + 1234 * n), file=sys.stderr)
'''

TRIVIAL_BENCH = '''\
import sys
n = int(sys.argv[sys.argv.index("--ticks") + 1])
x = 0.0
for i in range(n):
    x = x * 0.5 + i
'''


def run(args, insns):
    return subprocess.run([sys.executable, TICK_COST, "--insns", insns] + args,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)


@pytest.fixture
def fake_insns(tmp_path):
    script = tmp_path / "fake_insns"
    script.write_text("#!%s\n%s" % (sys.executable, FAKE_INSNS))
    script.chmod(0o755)
    return str(script)


def test_per_tick_arithmetic(fake_insns):
    p = run(["--ticks", "500", "--", "python3", "-m", "tipbot_fw.bench"], fake_insns)
    assert p.returncode == 0, p.stderr
    assert "python3 -m tipbot_fw.bench --ticks 500: 40617000 insns" in p.stdout
    assert "python3 -m tipbot_fw.bench --ticks 0: 40000000 insns" in p.stdout
    assert "tick-cost: 1234 instructions per tick (N=500;" in p.stdout


def test_failing_command_fails(fake_insns):
    p = run(["--", "python3", "x.py", "--fail"], fake_insns)
    assert p.returncode == 1
    assert "exited with status 1" in p.stderr and "boom" in p.stderr


def test_no_brick_says_how_to_make_one(tmp_path):
    env = dict(os.environ, ARMV5_ROOT=str(tmp_path / "none"), ARMV5_BUILD=str(tmp_path / "none"))
    p = subprocess.run([sys.executable, TICK_COST, "--", "python3", "-c", "pass"], env=env,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    assert p.returncode == 2
    assert "make brick" in p.stderr


def have_brick():
    root = os.environ.get("ARMV5_ROOT", "/var/tmp/armv5-root")
    build = os.environ.get("ARMV5_BUILD", "/var/tmp/armv5-build")
    return os.path.isfile(os.path.join(build, "libinsncount.so")) and \
        os.access(os.path.join(root, "usr", "bin", "python3"), os.X_OK)


@pytest.mark.slow
@pytest.mark.skipif(not have_brick(), reason="no virtual brick (make brick)")
def test_on_the_virtual_brick(tmp_path):
    bench = tmp_path / "trivial_bench.py"
    bench.write_text(TRIVIAL_BENCH)
    p = run(["--ticks", "2000", "--", "python3", str(bench)], INSNS)
    assert p.returncode == 0, p.stderr
    per_tick = float(p.stdout.split("tick-cost: ")[-1].split()[0])
    # one float multiply-add in CPython 3.11 on ARMv5 soft-float: hundreds to a few thousand insns
    assert 200 < per_tick < 20000, p.stdout


def test_the_brick_estimate_scales_the_count_to_the_brick_and_its_period(fake_insns):
    p = run(["--ticks", "500", "--period-ms", "5", "--", "python3", "-m", "tipbot_fw.bench"], fake_insns)
    assert p.returncode == 0, p.stderr
    # 1234 insns x 1.21 at 300 MHz = 0.005 ms, 0 % of 5 ms
    assert "tick-cost: brick estimate 0.00 ms a tick (x1.21 for its Python 3.5), 0 % of the 5 ms period" in p.stdout


def _mem_cost():
    import importlib.machinery
    import importlib.util
    loader = importlib.machinery.SourceFileLoader("mem_cost", os.path.join(REPO, "tools", "mem-cost"))
    spec = importlib.util.spec_from_loader("mem_cost", loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def test_mem_cost_counts_only_the_guest_mappings():
    """qemu-arm's smaps hold the 32-bit guest (below 4 GiB) and QEMU itself (above): only the
    guest's pages are the brick's."""
    smaps = ("00010000-00400000 r-xp 00000000 fe:00 1 /usr/bin/python3.11\nSize: 4032 kB\nRss: 2000 kB\n"
             "Pss: 1000 kB\n"
             "3f000000-3f100000 rw-p 00000000 00:00 0 \nRss: 300 kB\nPss: 300 kB\n"
             "563fdf5ec000-563fdf78c000 r-xp 00078000 fe:00 2 /usr/bin/qemu-arm\nRss: 1344 kB\nPss: 1344 kB\n")
    assert _mem_cost().guest_smaps_kb(smaps) == (2300, 1300)


def test_mem_cost_splits_a_page_between_the_runs_processes_that_map_it():
    """The run's own PSS: a page counts once for the run, split between those of its processes
    that map it; the three processes' PSS add up to the run's distinct pages."""
    import numpy as np
    mc = _mem_cost()
    page_kb = os.sysconf("SC_PAGE_SIZE") / 1024.0
    pages = {"supervisor": {"python3": np.array([1, 2, 3], dtype=np.uint64)},
             "guard": {"python3": np.array([1, 2, 4], dtype=np.uint64)},
             "controller": {"python3": np.array([1, 5], dtype=np.uint64), "[anon]": np.array([6], dtype=np.uint64)}}
    kb = mc.run_memory_kb(pages)
    assert kb["supervisor"]["python3"][0] == 3 * page_kb
    assert abs(kb["supervisor"]["python3"][1] - (1 / 3 + 1 / 2 + 1) * page_kb) < 1e-9
    assert abs(kb["controller"]["python3"][1] - (1 / 3 + 1) * page_kb) < 1e-9
    assert kb["controller"]["[anon]"] == [page_kb, page_kb]
    total = sum(mc.totals_kb(named)[1] for named in kb.values())
    assert abs(total - 6 * page_kb) < 1e-9


def test_the_whole_tick_bench_runs_on_the_real_device_layer_and_clock():
    p = subprocess.run([sys.executable, "-m", "tipbot_fw.bench", "--ticks", "40", "--whole"], cwd=REPO,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert "ticks 40 (+1 start tick)" in p.stdout and "whole (the device layer on files and the real clock)" in p.stdout
    p = subprocess.run([sys.executable, "-m", "tipbot_fw.bench", "--ticks", "4", "--whole", "--bare"], cwd=REPO,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    assert p.returncode == 2 and "usage" in p.stderr
