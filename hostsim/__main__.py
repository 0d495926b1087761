"""``python -m hostsim VERB ...``: every host tool, one command line.

Each verb's module has a ``main(argv) -> exit status`` whose parser is named
``hostsim.command(VERB)`` (as the owner started it: tipbot-host or python -m hostsim); the table maps verbs to modules, imported only when that verb runs,
so one tool's heavy imports cost the others nothing. To add a tool: write its main(argv), with
help on every option (tests/test_sim_cli.py checks), and list it here.
"""
import importlib
import sys

import hostsim

# verb: (module, one line for the list of verbs)
COMMANDS = {
    "gains": ("hostsim.model.gains", "design the gains and write gains/<variant>.json (make gains)"),
    "describe": ("hostsim.model.description", "describe your robot: scale and ruler entries -> a parameters file"),
    "paper-check": ("hostsim.model.paper_check", "the paper variant against Appendix C (make paper-check)"),
    "pd": ("hostsim.model.pd", "the Appendix D PD baseline designed for a gains file"),
    "motor-sim": ("hostsim.sim.motor_sim", "a simulated motor behind a fake EV3 (identify logs without a brick)"),
    "fake-robot": ("hostsim.sim.fake_robot", "the simulated robot behind a fake EV3 tree, in real time"),
    "run": ("hostsim.studies.runner", "run one scenario file: metrics.json, plots, summary"),
    "sim": ("hostsim.studies.sim_study", "the paper's scenarios + robustness summary -> out/sim/ (make sim)"),
    "montecarlo": ("hostsim.studies.montecarlo", "Monte Carlo robustness of the firmware in the loop"),
    "roa": ("hostsim.studies.roa", "region of attraction (largest recovered initial angles)"),
    "margins": ("hostsim.studies.margins", "how much of each brick imperfection the robot takes; what each costs"),
    "robot-study": ("hostsim.studies.robot_study", "owners' robots: describe, experiments, fit, gains, stand (issue 24)"),
    "push-limit": ("hostsim.studies.push_limit", "the largest push on link 3 any controller within u_max recovers (LP bound)"),
    "bench-sim": ("hostsim.studies.sim_bench", "simulation speed: real-time factor, Monte Carlo throughput"),
    "replay": ("hostsim.logs.replay", "replay a robot log on the host (make replay)"),
    "identify": ("hostsim.logs.identify", "identify motor parameters from identify logs"),
    "fit-robot": ("hostsim.model.robotfit", "fit the fall and swing tests into your robot's parameters file"),
    "watch": ("hostsim.logs.watch", "live telemetry from the robot: scrolling plots, recording (make watch)"),
    "drive": ("hostsim.logs.drive", "drive the robot from the keyboard over UDP (make drive)"),
    "export": ("hostsim.logs.export", "a robot log as CSV for spreadsheets and notebooks"),
    "docs": ("hostsim.studies.docblocks", "the docs pages' generated blocks from docs/data/ (make sim, make bench write them)"),
}


def usage():
    me = hostsim.command()
    lines = ["usage: %s VERB [ARGS...]   (%s VERB --help for its options;" % (me, me),
             "       tipbot-host VERB ... and python -m hostsim VERB ... are the same; make venv puts tipbot-host on PATH)",
             "", "verbs:"]
    lines += ["  %-12s %s" % (name, text) for name, (_, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    verb = argv[0]
    if verb not in COMMANDS:
        print("%s: unknown verb %r\n\n%s" % (hostsim.command(), verb, usage()), file=sys.stderr)
        return 2
    return importlib.import_module(COMMANDS[verb][0]).main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
