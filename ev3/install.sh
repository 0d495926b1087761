#!/bin/sh
# Checks that this brick can run tipbot and prints exactly what to install when it cannot.
# Run it on the brick, in the install directory (`make deploy` runs it for you).
#
# Usage: ./install.sh [--check]     check only (the default); exit status 1 if something is missing
#        ./install.sh --service     check, then install and enable tipbot.service (uses sudo) so
#                                   the controller starts at boot
#        ./install.sh --remove-service   disable and remove tipbot.service (uses sudo)
#        ./install.sh --rtprio      check, then let this user run SCHED_FIFO (uses sudo): writes
#                                   $LIMITS_DIR/tipbot.conf (default /etc/security/limits.d), which
#                                   pam_limits applies to every new login (ssh, `make run`; log in
#                                   again); tipbot.service has its own LimitRTPRIO
# Needs: ev3dev-stretch (Debian 9): python3 (3.5), python3-numpy (1.12), python3-ev3dev2 (2.1.0).
# $PYTHON names another interpreter (default python3).
#
# The check starts Python once (a start with numpy takes seconds on the brick): it reports the
# versions and byte-compiles tipbot_fw/ with the brick's own Python, so that syntax this Python
# lacks shows up now rather than at the first run, and the first run starts faster.
set -u
PYTHON=${PYTHON:-python3}
DIR=$(cd "$(dirname "$0")" && pwd)
missing=""
problems=0

say() { echo "install.sh: $*"; }

# One line per finding: "python VERSION ok|old", "numpy VERSION|- ok|old|missing",
# "ev3dev2 VERSION|- ok|other|missing", "compile - ok|failed|skipped", then compile errors.
PROBE='
import re, sys
def version(mod):
    try:
        m = __import__(mod)
    except Exception:
        return None
    return str(getattr(m, "__version__", "?"))
def major_minor(v):
    m = re.match(r"(\d+)\.(\d+)", v or "")
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)
ok = True
py = "%d.%d.%d" % sys.version_info[:3]
if sys.version_info < (3, 5):
    ok = False
print("python %s %s" % (py, "ok" if sys.version_info >= (3, 5) else "old"))
np = version("numpy")
if np is None or major_minor(np) < (1, 12):
    ok = False
print("numpy %s %s" % (np or "-", "missing" if np is None else "ok" if major_minor(np) >= (1, 12) else "old"))
ev = version("ev3dev2")
if ev is None:
    ok = False
print("ev3dev2 %s %s" % (ev or "-", "missing" if ev is None else "ok" if ev.startswith("2.1.0") else "other"))
if ok and len(sys.argv) > 1:
    import compileall, io
    out = io.StringIO()
    saved, sys.stdout = sys.stdout, out
    try:
        good = compileall.compile_dir(sys.argv[1], quiet=1)
    finally:
        sys.stdout = saved
    print("compile - %s" % ("ok" if good else "failed"))
    sys.stdout.write(out.getvalue())
else:
    print("compile - skipped")
'

if ! command -v "$PYTHON" >/dev/null 2>&1; then
    say "no $PYTHON"
    missing="$missing python3"
    problems=1
else
    if [ -d "$DIR/tipbot_fw" ]; then
        report=$("$PYTHON" -c "$PROBE" "$DIR/tipbot_fw" 2>&1)
    else
        report=$("$PYTHON" -c "$PROBE" 2>&1)
    fi
    pyver=$(echo "$report" | sed -n 's/^python \([^ ]*\) .*/\1/p')
    while read -r what ver verdict; do
        case "$what $verdict" in
            "python ok") say "python $ver: ok" ;;
            "python old")
                say "python $ver: too old, tipbot needs Python 3.5 or newer (ev3dev-stretch has 3.5.3)"
                missing="$missing python3"; problems=1 ;;
            "numpy ok") say "numpy $ver: ok" ;;
            "numpy old")
                say "numpy $ver: too old, tipbot needs numpy 1.12 or newer"
                missing="$missing python3-numpy"; problems=1 ;;
            "numpy missing")
                say "numpy: not installed"
                missing="$missing python3-numpy"; problems=1 ;;
            "ev3dev2 ok") say "python-ev3dev2 $ver: ok" ;;
            "ev3dev2 other") say "python-ev3dev2 $ver: tipbot is tested with 2.1.0 (may still work)" ;;
            "ev3dev2 missing")
                say "python-ev3dev2: not installed"
                missing="$missing python3-ev3dev2"; problems=1 ;;
            "compile ok") say "tipbot_fw: compiles with python $pyver" ;;
            "compile failed")
                say "tipbot_fw does not compile with python $pyver:"
                echo "$report" | sed -n '/^compile - failed/,$p' | sed -e '1d' -e 's/^/    /'
                problems=1 ;;
        esac
    done <<EOF
$report
EOF
    if [ -z "$pyver" ]; then
        say "$PYTHON does not run:"
        echo "$report" | sed 's/^/    /'
        missing="$missing python3"
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
case "${1:---check}" in
    --remove-service)
        say "removing /etc/systemd/system/tipbot.service"
        sudo systemctl disable --now tipbot.service
        sudo rm -f /etc/systemd/system/tipbot.service && sudo systemctl daemon-reload
        exit $?
        ;;
esac
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
    --rtprio)
        # the loop asks for SCHED_FIFO 50 and the supervisor one above (config realtime_priority)
        limits="${LIMITS_DIR:-/etc/security/limits.d}/tipbot.conf"
        say "granting $(id -un) real-time priority up to 60: $limits (log in again for it to apply)"
        printf '# tipbot (install.sh --rtprio): the balancing loop and its supervisor run SCHED_FIFO\n%s - rtprio 60\n' \
            "$(id -un)" | sudo tee "$limits" >/dev/null
        exit $?
        ;;
    *) echo "usage: $0 [--check|--service|--remove-service|--rtprio]" >&2; exit 2 ;;
esac
