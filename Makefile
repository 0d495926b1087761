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

# make gains TS=0.010 VARIANT=paper
TS       ?=
VARIANT  ?=
# make test PYTEST_ARGS='-k gains -x'
PYTEST_ARGS ?=
# make bench TICKS=2000
TICKS    ?= 1000
# make deploy HOST=robot@ev3dev.local [REMOTE_DIR=tipbot] [DEPLOY_VARIANT=physical] [CONFIG=my.json]
HOST     ?=
REMOTE_DIR ?= tipbot
DEPLOY_VARIANT ?= $(if $(VARIANT),$(VARIANT),physical)
CONFIG   ?=
SSH      ?= ssh
STAGE    := build/ev3
# make replay LOG=logs/ev3dev/run-....log
LOG      ?=

.DEFAULT_GOAL := help
.PHONY: help venv test gains paper-check sim replay bench brick stage deploy run logs clean distclean

help:
	@echo "tipbot make targets (Python ones run in $(VENV), made by 'make venv'):"
	@echo "  venv         create/update $(VENV) from $(REQ) (idempotent)"
	@echo "  test         run the test suite (pytest tests/; PYTEST_ARGS=...)"
	@echo "  sim          run the firmware on the simulated robot"
	@echo "  gains        regenerate gains/*.json (TS=0.010 VARIANT=paper|physical)"
	@echo "  paper-check  compare the paper variant's gains with the paper's Appendix C"
	@echo "  replay       replay a robot log on the host (LOG=file)"
	@echo "  bench        guest instructions per control tick on the virtual brick (TICKS=N)"
	@echo "  brick        set up the virtual brick for 'make bench' (root, ~2 min)"
	@echo "  deploy       copy firmware+gains to the brick (HOST=robot@ev3dev.local)"
	@echo "  run          start the controller on the brick over ssh (HOST=...)"
	@echo "  logs         fetch the brick's run logs into logs/<host>/ (HOST=...)"
	@echo "  clean        remove build products and caches; distclean also removes $(VENV)"

venv: $(STAMP)

$(STAMP):
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
	  { echo "make venv: needs Python 3.11+ as $(PYTHON) (the pins in $(REQ)); set PYTHON=..." >&2; exit 1; }
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --disable-pip-version-check --no-input --quiet --prefer-binary -r $(REQ)
	$(VPY) -m pip check
	@touch $@
	@echo "make venv: $(VENV) ready ($$($(VPY) --version))"

test: venv
	@$(VPY) -m pytest tests $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests (exit status 5): failing" >&2; fi; \
	exit $$rc

gains: venv
	$(VPY) -m hostsim.gains $(if $(TS),--ts $(TS)) $(if $(VARIANT),--variant $(VARIANT))

paper-check: venv
	$(VPY) -m hostsim.paper_check

sim: venv
	$(VPY) -m hostsim sim $(SIM_ARGS)

replay: venv
	@test -n "$(LOG)" || { echo "usage: make replay LOG=path/to/run.log" >&2; exit 2; }
	$(VPY) -m hostsim replay $(LOG)

# Instructions per control tick of tipbot_fw.bench on the virtual brick (an ARM926 under QEMU
# with Debian armel's Python 3.11 + numpy 1.24: an approximation of the brick's Python 3.5 +
# numpy 1.12, see README). Without the brick it says how to make one.
bench: venv
	$(VPY) tools/tick-cost --ticks $(TICKS) -- python3 -m tipbot_fw.bench

brick:
	tools/brick-setup

# What goes onto the brick, laid out as on the brick (see ev3/tipbot).
stage:
	@test -f gains/$(DEPLOY_VARIANT).json || { echo "no gains/$(DEPLOY_VARIANT).json: run 'make gains'" >&2; exit 1; }
	rm -rf $(STAGE)
	mkdir -p $(STAGE)
	tar -cf - --exclude=__pycache__ --exclude='*.pyc' tipbot_fw | tar -C $(STAGE) -xf -
	install -m 755 ev3/tipbot ev3/install.sh $(STAGE)/
	install -m 644 ev3/tipbot.service $(STAGE)/
	install -m 644 gains/$(DEPLOY_VARIANT).json $(STAGE)/gains.json
	$(if $(CONFIG),install -m 644 $(CONFIG) $(STAGE)/config.json)
	@echo "staged in $(STAGE): gains $(DEPLOY_VARIANT)$(if $(CONFIG), config $(CONFIG))"

define need_host
	@test -n "$(HOST)" || { echo "usage: make $@ HOST=robot@ev3dev.local" >&2; exit 2; }
endef

# Copies the staged tree to ~/$(REMOTE_DIR) on the brick (tar over ssh: the brick needs nothing
# but tar), replacing the old tipbot_fw/ and keeping logs/, then checks the brick's packages.
deploy: stage
	$(need_host)
	tar -C $(STAGE) -cf - . | $(SSH) $(HOST) 'set -e; mkdir -p $(REMOTE_DIR); rm -rf $(REMOTE_DIR)/tipbot_fw; tar -C $(REMOTE_DIR) -xf -; $(REMOTE_DIR)/install.sh --check'

run:
	$(need_host)
	$(SSH) $(if $(shell test -t 0 && echo tty),-t) $(HOST) '$(REMOTE_DIR)/tipbot $(RUN_ARGS)'

logs:
	$(need_host)
	mkdir -p logs/$(lastword $(subst @, ,$(HOST)))
	$(SSH) $(HOST) 'cd $(REMOTE_DIR) && mkdir -p logs && tar -cf - logs' | tar -C logs/$(lastword $(subst @, ,$(HOST))) --strip-components=1 -xvf -

clean:
	rm -rf build dist *.egg-info .pytest_cache .cache
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
