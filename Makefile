# Quick start: `make demo` (set up and run the main job) and `make test` (set up and run every test).
# Both create .venv and install the project with every extra (sim, view, cluster, test; `pip install .`
# alone is the controller-only core: docs/DEPLOY.md); as root they also apt-get install
# user-mode-linux, kmod and can-utils when missing (the vcan sandbox and the CAN peer tools), and
# chromium (the live view's browser tests drive it with playwright).

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
AIDER  := $(VENV)/bin/aider-exo
STAMP  := $(VENV)/.installed
SYSTEM_TOOLS := linux insmod candump canplayer cangen chromium cc
# the per-tick numerics that the install compiles (protocol/compiled.py's MODULES) and their C types:
# an edit reinstalls, which compiles them again
COMPILED := $(shell sed -n 's/^    "\([a-z_.0-9]*\)",$$/\1/p' protocol/compiled.py | tr . /)
COMPILED_SOURCES := $(COMPILED:=.py) $(wildcard $(COMPILED:=.pxd))

.PHONY: demo test venv system-deps docs perf clean

venv: $(STAMP)

$(STAMP): pyproject.toml setup.py protocol/compiled.py $(COMPILED_SOURCES)
	@test -n "$(PYTHON)" || { echo "make: no python3 found (Python 3.11 or newer needed)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[sim,view,cluster,test]'
	@touch $(STAMP)

# The vcan sandbox (user-mode Linux + kmod), can-utils (candump, canplayer, cangen), chromium, and the
# C compiler and Python headers that compile the per-tick numerics (before the venv's install).
system-deps:
	@missing=""; for t in $(SYSTEM_TOOLS); do command -v $$t >/dev/null 2>&1 || [ -x /usr/sbin/$$t ] || [ -x /sbin/$$t ] || missing="$$missing $$t"; done; \
	$(PYTHON) -c "import os, sysconfig, sys; sys.exit(not os.path.isfile(os.path.join(sysconfig.get_paths()['include'], 'Python.h')))" || missing="$$missing Python.h"; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		echo "installing user-mode-linux kmod can-utils chromium gcc python3-dev (missing:$$missing)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq user-mode-linux kmod can-utils chromium gcc python3-dev >/dev/null; \
	else \
		echo "warning: missing$$missing; install user-mode-linux kmod can-utils chromium gcc python3-dev (as root) or the vcan and browser tests cannot run and the numerics run interpreted: docs/TESTING.md"; \
	fi

# The main job: the main controller walks the simulated HHEA through the four emulated node boards,
# every value a CAN frame, in lock-step at real time, with the live view of the walk served on
# http://127.0.0.1:8050/ (docs/VIEW.md); the walk is rendered to build/walk (PNG strip and GIF).
demo: system-deps venv
	$(AIDER) walk --steps 10 --render build/walk --view

# Three stages: the host tests on every core; the real-time walks alone (beside another worker
# they overrun on a 2-core machine); the vcan tests in the sandbox. Each lists its slowest tests,
# where the suite's time goes (it must stay under 20 minutes on a 2-core machine).
test: system-deps venv
	$(PY) -m pytest -m "not vcan and not realtime" -n auto --durations=8
	$(PY) -m pytest -m realtime -p no:cacheprovider --durations=8
	tools/vcan-run -- $(PY) -m pytest -m vcan -p no:cacheprovider --durations=8

# Regenerate the protocol documentation from the DBC and the generated blocks of docs/FIRMWARE.md and
# docs/TRACE.md (tools/docgen.py; a test fails when any is stale), and the live view's picture in the
# README: a recorded two-cycle walk played to the page in a headless chromium.
docs: system-deps venv
	$(AIDER) protocol --markdown > docs/PROTOCOL.md
	$(PY) -m tools.docgen
	mkdir -p build
	$(AIDER) trace record build/view-walk.log --walk 2 --seed 0 --overwrite
	$(AIDER) view --trace build/view-walk.log --speed 4 --port 0 --screenshot docs/view.png

# Every benchmark, each its own process, into docs/perf/NAME.json, and docs/PERFORMANCE.md's table
# made from them (a test fails when the two disagree). Run it on an otherwise idle machine.
perf: system-deps venv
	$(AIDER) bench all --out docs/perf
	$(AIDER) bench table docs/perf --update docs/PERFORMANCE.md
	$(PY) -m tools.docgen --block trace-bench docs/TRACE.md

clean:
	rm -rf $(VENV) build .pytest_cache .hypothesis
