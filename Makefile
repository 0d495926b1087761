# tipbot: host tools, tests and deployment. Every Python target runs in .venv, which `make venv`
# builds from requirements-host.txt (and rebuilds when that file or the base python changes).
# `make help` lists the targets.

PYTHON   ?= python3
VENV     ?= .venv
VPY      := $(VENV)/bin/python
REQ      := requirements-host.txt
# The stamp's name is keyed on the requirements file and the base interpreter's version.
VENV_KEY := $(shell { cat $(REQ); $(PYTHON) -c 'import sys; print(sys.version)'; } 2>/dev/null | sha256sum | cut -c1-16)
STAMP    := $(VENV)/.tipbot-venv-$(VENV_KEY)

# make gains TS=0.010 VARIANT=paper PARAMS=identified.json [GAINS_DIR=gains]
# (another TS or PARAMS writes its own file, e.g. gains/physical-ts0.010.json)
TS       ?=
PARAMS   ?=
VARIANT  ?=
GAINS_DIR ?=
# make test PYTEST_ARGS='-k gains -x'
PYTEST_ARGS ?=
# make bench TICKS=2000
TICKS    ?= 1000
# make deploy HOST=robot@ev3dev.local [REMOTE_DIR=tipbot] [DEPLOY_VARIANT=physical] [CONFIG=my.json]
#             [SERVICE=1] [SSH='ssh -F my_ssh_config']      (tools/deploy; host needs only python3 + ssh)
#             [REMOVE_CONFIG=1: remove the brick's config.json] [FORCE=1: deploy gains not robust]
# make run HOST=... [DURATION=10] [RUN_ARGS='--sysfs-root DIR']; make logs HOST=... [LOGS_DIR=dir]
HOST     ?=
REMOTE_DIR ?= tipbot
DEPLOY_VARIANT ?= $(if $(VARIANT),$(VARIANT),physical)
CONFIG   ?=
REMOVE_CONFIG ?=
FORCE    ?=
SERVICE  ?=
SSH      ?= ssh
STAGE    ?= build/ev3
DURATION ?=
RUN_ARGS ?=
LOGS_DIR ?=
DEPLOY   = $(PYTHON) tools/deploy
CONNECT  = $(HOST) --remote-dir '$(REMOTE_DIR)' --ssh "$(SSH)"
# make replay LOG=logs/ev3dev.local/tipbot-....log [GAINS=other.json] [REPLAY_ARGS=...]
LOG      ?=
GAINS    ?=
REPLAY_ARGS ?=
# make watch HOST=... [DURATION=s] [WATCH_PORT=5005] [RECORD=file.csv] [SNAPSHOT=file.png]
WATCH_PORT ?= 5005
DRIVE_PORT ?= 5006
RECORD   ?=
SNAPSHOT ?=
# make bench TELEMETRY_EVERY=20: the decimation of the telemetry bench (the firmware's default)
TELEMETRY_EVERY ?= 20
# make bench MEM_SECONDS=60: the seconds of ticks after which tools/mem-cost reads the run's memory
MEM_SECONDS ?= 60

.DEFAULT_GOAL := help
.PHONY: help venv test test-fast gains paper-check sim replay bench bench-steps brick stage deploy run drive logs watch sim-brick \
        sim-brick-stop clean distclean

help:
	@echo "tipbot make targets (Python ones run in $(VENV), made by 'make venv'):"
	@echo "  venv         create/update $(VENV) from $(REQ) (idempotent)"
	@echo "  test         run the whole test suite, as CI does (pytest tests/; PYTEST_ARGS=...)"
	@echo "  test-fast    the suite without the tests marked slow (real processes, whole studies)"
	@echo "  sim          paper scenarios + robustness, firmware in the loop -> out/sim/report.md"
	@echo "               (and its tables into docs/results.md, docs/realistic-brick.md: docs/data/sim.json)"
	@echo "  gains        regenerate gains/*.json; unchanged within tolerance: left as they are"
	@echo "               (TS=0.010 VARIANT=paper|physical PARAMS=file: another TS/PARAMS gets its own file)"
	@echo "  paper-check  compare the paper variant's gains with the paper's Appendix C"
	@echo "  replay       replay a robot log on the host (LOG=file; GAINS=other.json)"
	@echo "  bench        simulation real-time factor; instructions per tick and memory on the virtual brick"
	@echo "               (and its output and tables into docs/benchmarks.md: docs/data/bench.json)"
	@echo "  brick        set up the virtual brick for 'make bench' (root, 5-10 min)"
	@echo "  stage        lay out what deploy copies, in $(STAGE) (DEPLOY_VARIANT=, CONFIG=)"
	@echo "  deploy       copy what changed to the brick over ssh (HOST=robot@ev3dev.local; CONFIG=file,"
	@echo "               REMOVE_CONFIG=1, DEPLOY_VARIANT=physical-ts0.010, FORCE=1, SERVICE=1)"
	@echo "  run          run the controller on the brick over ssh (HOST=...; DURATION=s; COURSE=file: drive it)"
	@echo "  drive        run on the brick and drive it from the keyboard (HOST=...; arrows/WASD, space, q)"
	@echo "  logs         fetch the brick's new run logs into logs/<host>/ (HOST=...)"
	@echo "  watch        run on the brick with live telemetry plotted here (HOST=...; DURATION=s,"
	@echo "               RECORD=file.csv, SNAPSHOT=file.png, WATCH_PORT=5005)"
	@echo "  sim-brick    a brick without a brick: loopback sshd + simulated robot; prints HOST= and SSH="
	@echo "  sim-brick-stop  stop it (or Ctrl-C where it runs)"
	@echo "  clean        remove build products and caches; distclean also removes $(VENV)"

venv: $(STAMP)

$(STAMP):
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
	  { echo "make venv: needs Python 3.11+ as $(PYTHON) (the pins in $(REQ)); set PYTHON=..." >&2; exit 1; }
	@# one shell for the whole build: Ctrl-C on a terminal (it reaches make too) ends it with pip's
	@# one line and no stamp, so the next make builds the venv again; not make's error line after it.
	@# Last, the host commands on PATH (tipbot-host VERB) from this checkout (pip builds it with a
	@# setuptools and wheel of its own, from the same package index).
	@trap 'interrupted=1' INT; \
	  build() { \
	    echo "make venv: building $(VENV) from $(REQ) (about a minute)"; \
	    rm -rf $(VENV) && $(PYTHON) -m venv $(VENV) && \
	    $(VPY) -m pip install --disable-pip-version-check --no-input --quiet --prefer-binary -r $(REQ) && \
	    $(VPY) -m pip check || return; \
	    $(VPY) -m pip install --disable-pip-version-check --no-input --quiet --no-deps -e . || [ -n "$$interrupted" ] \
	      || echo "make venv: tipbot-host not installed (pip install -e . failed; python -m hostsim works)"; \
	  }; \
	  build; rc=$$?; [ -z "$$interrupted" ] || exit 0; [ $$rc -eq 0 ] || exit $$rc; \
	  touch $@; echo "make venv: $(VENV) ready ($$($(VPY) --version))"

test-fast: venv
	@$(VPY) -m pytest tests -m "not slow" -q $(PYTEST_ARGS)

test: venv
	@$(VPY) -m pytest tests $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests (exit status 5): failing" >&2; fi; \
	exit $$rc

gains: venv
	$(VPY) -m hostsim gains $(if $(TS),--ts $(TS)) $(if $(VARIANT),--variant $(VARIANT)) $(if $(PARAMS),--params $(PARAMS)) \
	  $(if $(GAINS_DIR),--out-dir $(GAINS_DIR))

paper-check: venv
	$(VPY) -m hostsim paper-check

# Ctrl-C on a terminal reaches make as well as the study: the study's one line is all that is
# printed and make ends on the signal (status 130); a SIGINT to the study alone fails as usual
sim: venv
	@trap 'interrupted=1' INT; $(VPY) -m hostsim sim $(SIM_ARGS); rc=$$?; \
	  if [ $$rc -eq 130 ] && [ -n "$$interrupted" ]; then exit 0; fi; exit $$rc

replay: $(if $(LOG),venv)
	@test -n "$(LOG)" || { echo "usage: make replay LOG=path/to/run.log [GAINS=other.json]" >&2; exit 2; }
	$(VPY) -m hostsim replay $(LOG) $(if $(GAINS),--gains $(GAINS)) $(REPLAY_ARGS)

# Instructions per control tick of tipbot_fw.bench on the virtual brick (an ARM926 under QEMU
# with Debian armel's Python 3.11 + numpy 1.24: an approximation of the brick's Python 3.5 +
# numpy 1.12, see docs/benchmarks.md). Without the brick it says how to make one.
# make bench tees what its steps print to out/bench/output.txt; docs/benchmarks.md's generated
# blocks are written from it (python -m hostsim docs --bench) when every step succeeded
bench: venv
	@mkdir -p out/bench
	@{ $(MAKE) --no-print-directory bench-steps 2>&1; echo $$? >out/bench/status; } | tee out/bench/output.txt; \
	  exit $$(cat out/bench/status)
	@$(VPY) -m hostsim docs --bench out/bench/output.txt

bench-steps: venv
	$(VPY) -m hostsim bench-sim
	@echo "== the control tick as it runs supervised: heartbeat, plausibility checks, log chunks to a file"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench
	@echo "== the same tick bare (without those three), for what they cost"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --bare
	@echo "== the supervised tick with telemetry (one datagram every $(TELEMETRY_EVERY) ticks)"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --telemetry-every $(TELEMETRY_EVERY)
	@$(VPY) -m tipbot_fw.bench --ticks $(TICKS) --telemetry-every $(TELEMETRY_EVERY) | grep '^telemetry:'
	@echo "== the supervisor: instructions per poll (it polls every 10 ms, outside the controller's ticks)"
	$(VPY) tools/tick-cost --ticks $(TICKS) --ticks-flag=--bench-polls -- python3 -m tipbot_fw.supervisor
	@echo "== the device layer's own cost (5 reads, 4 writes per tick, beside the tick's)"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --device-layer
	@echo "== the supervised tick while driving a course (its row of the drive plan copied each tick)"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --drive
	@echo "== the same, its rows made in the slack and corrected from the robot's pose (the path follower, between ticks)"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --drive --follow
	@echo "== the supervised tick driven by a remote (the receiver polled every 4 ticks, the live plan's rows made in batches in the slack)"
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench --remote
	@echo "== the whole tick as the brick pays it: supervised, the device layer on files and the real clock"
	$(VPY) tools/tick-cost --ticks $(TICKS) --period-ms 5 -- python3 -m tipbot_fw.bench --whole
	@echo "== memory: the supervisor, its guard and the controller of a supervised run (RSS, PSS)"
	$(VPY) tools/mem-cost --seconds $(MEM_SECONDS)

brick:
	tools/brick-setup

# What goes onto the brick, laid out as in its install directory (for inspection; deploy
# stages in memory and writes the same tree here).
stage:
	$(DEPLOY) stage --variant $(DEPLOY_VARIANT) $(if $(CONFIG),--config $(CONFIG)) --stage $(STAGE) \
	  $(if $(FORCE),--force)

define need_host
	@test -n "$(HOST)" || { echo "usage: make $@ HOST=robot@ev3dev.local" >&2; exit 2; }
endef

# Sends only what changed since the last deploy (sha256 manifest, tar over one ssh connection;
# the brick needs nothing but sh and tar), removes what is no longer deployed, keeps logs/ and
# the brick's config.json (REMOVE_CONFIG=1 removes it), then checks the brick's Python, numpy
# and ev3dev2 (install.sh --check). SERVICE=1 also installs the systemd unit. Gains whose file
# says they do not stabilize the model(s) they must also hold are refused unless FORCE=1.
deploy:
	$(need_host)
	$(DEPLOY) deploy $(CONNECT) --variant $(DEPLOY_VARIANT) $(if $(CONFIG),--config $(CONFIG)) \
	  --stage $(STAGE) $(if $(SERVICE),--service) $(if $(REMOVE_CONFIG),--remove-config) $(if $(FORCE),--force)

# Runs the launcher on the brick in the foreground and reports its exit status (Ctrl-C: the
# firmware stops the motors and writes its log).
run:
	$(need_host)
	$(DEPLOY) run $(CONNECT) $(if $(DURATION),--duration $(DURATION)) $(if $(COURSE),--course "$(COURSE)") -- $(RUN_ARGS)

# Fetches the run logs not yet here (and the brick's gains.json, as gains-<sha256>.json) into
# logs/<host>/ (LOGS_DIR=... elsewhere).
logs:
	$(need_host)
	$(DEPLOY) logs $(CONNECT) $(if $(LOGS_DIR),--dest $(LOGS_DIR))

# Live plots of the run's telemetry: `hostsim watch` listens on WATCH_PORT and runs `make run`'s
# command, whose firmware sends its telemetry to the address the ssh connection comes from.
watch: $(if $(HOST),venv)
	$(need_host)
	$(VPY) -m hostsim watch --port $(WATCH_PORT) $(if $(RECORD),--record $(RECORD)) \
	  $(if $(SNAPSHOT),--snapshot $(SNAPSHOT)) -- \
	  $(DEPLOY) run $(CONNECT) --telemetry-port $(WATCH_PORT) $(if $(DURATION),--duration $(DURATION)) -- $(RUN_ARGS)

# Keyboard driving: `hostsim drive` sends the keys' commands to the brick's address (what ssh
# resolves HOST to) and runs `make run`'s command with --remote DRIVE_PORT; q or Ctrl-C ends both.
drive: $(if $(HOST),venv)
	$(need_host)
	$(VPY) -m hostsim drive --port $(DRIVE_PORT) \
	  --to "$$($(SSH) -G $(HOST) | awk '/^hostname /{print $$2; exit}')" -- \
	  $(DEPLOY) run $(CONNECT) $(if $(DURATION),--duration $(DURATION)) -- --remote $(DRIVE_PORT) $(RUN_ARGS)

# The loopback brick (tools/sim-brick): runs in the foreground until Ctrl-C or `make sim-brick-stop`.
sim-brick: venv
	$(VPY) tools/sim-brick start --python $(abspath $(VPY))

sim-brick-stop:
	$(PYTHON) tools/sim-brick stop

clean:
	rm -rf build dist *.egg-info .pytest_cache .cache
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
