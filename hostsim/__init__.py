"""Host-side tools for tipbot: model, gain design, simulator, fake EV3, replay."""
import os
import sys

CONSOLE_SCRIPT = "tipbot-host"


def command(verb=None):
    """How the host's command line is called in its messages: as it was started (the console
    script `tipbot-host` that make venv installs, or `python -m hostsim`), with a verb."""
    base = CONSOLE_SCRIPT if os.path.basename(sys.argv[0] or "") == CONSOLE_SCRIPT else "python -m hostsim"
    return base if verb is None else "%s %s" % (base, verb)
