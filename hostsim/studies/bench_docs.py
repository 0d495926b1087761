"""``make bench``'s generated blocks in docs/benchmarks.md (hostsim.studies.docblocks): its output, the
instructions per tick of each bench and the run's memory, from the output ``make bench`` saved.

``make bench`` tees what its steps print to out/bench/output.txt, then runs
``python -m hostsim docs --bench out/bench/output.txt``: ``payload`` keeps the lines the tools
printed (not make's echo of each command, nor tick-cost's two raw counts) in docs/data/bench.json.
"""
import re

ECHO = re.compile(r"^\S*python3?\s")                        # make's echo of a command it runs
RAW_COUNT = re.compile(r"^tick-cost: .*: \d+ insns$")       # the two counts a per-tick figure is made of
TICK = re.compile(r"^tick-cost: (\d+) instructions per tick \(N=(\d+); >= ([\d.]+) ms/tick")
SECTION = re.compile(r"^== (.*)$")
PROGRESS = re.compile(r"^[^:]+: (\d+ to do|\d+/\d+ done\b.*)$")   # hostsim.sim.parallel.Progress, on stderr


def payload(text):
    lines = [l.rstrip() for l in text.splitlines()]
    return {"output": [l for l in lines if l and not ECHO.match(l) and not RAW_COUNT.match(l)
                       and not PROGRESS.match(l) and not l.startswith("make")]}


def output(data):
    return "```\n" + "\n".join(data["output"]) + "\n```"


def ticks(data):
    """One row per tick-cost figure, named by the section (== ...) it is printed in."""
    out = ["| what is counted | ARMv5 instructions per tick | at 300 MHz, 1 instruction a cycle |", "|---|---|---|"]
    section, notes = "-", []
    for line in data["output"]:
        m = SECTION.match(line)
        if m:
            section = m.group(1)
            continue
        m = TICK.match(line)
        if m:
            out.append("| %s | %s | >= %s ms |" % (section, "{:,}".format(int(m.group(1))), m.group(3)))
        elif line.startswith("tick-cost: "):
            notes.append(line[len("tick-cost: "):])
    if len(out) == 2:
        raise ValueError("docs/data/bench.json: no tick-cost figure in make bench's output")
    return "\n".join(out) + "".join("\n\n" + n[0].upper() + n[1:] + "." for n in notes)


def memory(data):
    """mem-cost's table as markdown: the columns of its header line, a trailing (...) as a note."""
    lines = data["output"]
    start = next(i for i, l in enumerate(lines) if l.startswith("mem-cost:"))
    cells = [re.split(r"\s{2,}", l.strip()) for l in lines[start + 1:] if l.startswith("  ")]
    head, rows = cells[0], cells[1:]
    notes = [r.pop() for r in rows if r[-1].startswith("(")]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r + [""] * (len(head) - len(r))) + " |" for r in rows]
    title = lines[start][len("mem-cost: "):]
    return title[0].upper() + title[1:] + ".\n\n" + "\n".join(out) + "".join("\n\n" + n for n in notes)


BLOCKS = {
    "bench-output": ("docs/benchmarks.md", output),
    "bench-ticks": ("docs/benchmarks.md", ticks),
    "bench-memory": ("docs/benchmarks.md", memory),
}
