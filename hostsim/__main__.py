"""``python -m hostsim COMMAND ...``: the host tools' command line.

Each command lives in its own module with a ``main(argv) -> exit status``; the table below
maps names to modules, imported only when that command runs (so a command's heavy imports,
or a module not written yet, cost nothing to the others). To add one (``replay``,
``identify``, ...): write hostsim/<module>.py with main(argv) and list it here.
"""
import importlib
import sys

COMMANDS = {
    "run": ("hostsim.studies.runner", "run one scenario file: metrics.json, plots, summary"),
    "sim": ("hostsim.studies.sim_study", "the paper's scenarios + robustness summary -> out/sim/ (make sim)"),
    "montecarlo": ("hostsim.studies.montecarlo", "Monte Carlo robustness of the firmware in the loop"),
    "roa": ("hostsim.studies.roa", "region of attraction (largest recovered initial angles)"),
    "bench": ("hostsim.studies.sim_bench", "simulation speed: real-time factor, Monte Carlo throughput"),
    "replay": ("hostsim.logs.replay", "replay a robot log on the host"),
    "identify": ("hostsim.logs.identify", "identify parameters from logs"),
}


def usage():
    lines = ["usage: python -m hostsim COMMAND [ARGS...]", "", "commands:"]
    lines += ["  %-11s %s" % (name, text) for name, (_, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name = argv[0]
    if name not in COMMANDS:
        print("python -m hostsim: unknown command %r\n\n%s" % (name, usage()), file=sys.stderr)
        return 2
    module_name = COMMANDS[name][0]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name != module_name:
            raise
        print("python -m hostsim %s: not available yet (%s is not written)" % (name, module_name), file=sys.stderr)
        return 2
    return module.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
