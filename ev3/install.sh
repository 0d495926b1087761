#!/bin/sh
# Checks that this brick can run tipbot and prints exactly what to install when it cannot.
# Run it on the brick, in the install directory (`make deploy` runs it for you).
#
# Usage: ./install.sh [--check]     check only (the default); exit status 1 if something is missing
#        ./install.sh --service     check, then install and enable tipbot.service (uses sudo) so
#                                   the controller starts at boot
# Needs: ev3dev-stretch (Debian 9): python3 (3.5), python3-numpy (1.12), python3-ev3dev2 (2.1.0).
# $PYTHON names another interpreter (default python3).
set -u
PYTHON=${PYTHON:-python3}
DIR=$(cd "$(dirname "$0")" && pwd)
missing=""
problems=0

say() { echo "install.sh: $*"; }

if ! command -v "$PYTHON" >/dev/null 2>&1; then
    say "no $PYTHON"
    missing="$missing python3"
    problems=1
else
    pyver=$("$PYTHON" -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])')
    if "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 5))'; then
        say "python $pyver: ok"
    else
        say "python $pyver: too old, tipbot needs Python 3.5 or newer (ev3dev-stretch has 3.5.3)"
        missing="$missing python3"
        problems=1
    fi
    if npver=$("$PYTHON" -c 'import numpy; print(numpy.__version__)' 2>/dev/null); then
        if "$PYTHON" -c 'import sys, numpy; v = tuple(int(x) for x in numpy.__version__.split(".")[:2]); sys.exit(v < (1, 12))'; then
            say "numpy $npver: ok"
        else
            say "numpy $npver: too old, tipbot needs numpy 1.12 or newer"
            missing="$missing python3-numpy"
            problems=1
        fi
    else
        say "numpy: not installed"
        missing="$missing python3-numpy"
        problems=1
    fi
    if evver=$("$PYTHON" -c 'import ev3dev2; print(ev3dev2.__version__)' 2>/dev/null); then
        case "$evver" in
            2.1.0*) say "python-ev3dev2 $evver: ok" ;;
            *) say "python-ev3dev2 $evver: tipbot is tested with 2.1.0 (may still work)" ;;
        esac
    else
        say "python-ev3dev2: not installed"
        missing="$missing python3-ev3dev2"
        problems=1
    fi
fi
if [ ! -x "$DIR/tipbot" ]; then
    say "$DIR/tipbot is missing or not executable: run \`make deploy HOST=...\` again (or chmod u+x $DIR/tipbot)"
    problems=1
fi
if [ ! -f "$DIR/gains.json" ]; then
    say "$DIR/gains.json is missing: run \`make deploy HOST=...\` again"
    problems=1
fi

if [ -n "$missing" ]; then
    echo
    echo "To install what is missing, run on the brick:"
    echo "    sudo apt-get update && sudo apt-get install$missing"
fi
if [ "$problems" != 0 ]; then
    exit 1
fi

case "${1:---check}" in
    --check) say "ready: start it with $DIR/tipbot (or from brickman's File Browser)" ;;
    --service)
        unit=$(mktemp)
        sed -e "s|^User=.*|User=$(id -un)|" \
            -e "s|^WorkingDirectory=.*|WorkingDirectory=$DIR|" \
            -e "s|^ExecStart=.*|ExecStart=$DIR/tipbot|" "$DIR/tipbot.service" > "$unit"
        say "installing /etc/systemd/system/tipbot.service (starts $DIR/tipbot at boot)"
        sudo install -m 644 "$unit" /etc/systemd/system/tipbot.service &&
            sudo systemctl daemon-reload && sudo systemctl enable tipbot.service
        rc=$?
        rm -f "$unit"
        exit $rc
        ;;
    *) echo "usage: $0 [--check|--service]" >&2; exit 2 ;;
esac
