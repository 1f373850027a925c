# Two commands on a fresh machine: `make demo` and `make test` (both set everything up first).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.rt2-installed
# Foxglove's own node clients (the live view's tests run its classic client); skipped where npm is absent
NODE_CLIENTS := build/node/node_modules/.bin/ws-protocol-examples
JOBS   ?= 2

TESTS  ?=
JUNIT  ?=
RUNS   ?= 5
# TESTS: pytest arguments that narrow `make test` (files, -k EXPR); JUNIT: a folder for JUnit XML reports
JUNIT_OPT = $(if $(JUNIT),--junitxml=$(JUNIT)/$(1).xml)

.PHONY: setup demo test test-all bench clean clean-numba clean-cache flaky slowest stop-times

setup: $(STAMP) $(NODE_CLIENTS)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[train,test]"
	# camera drivers, Ray and the other arms' URDFs are optional extras; their tests run where they install, skip elsewhere
	$(PY) -m pip install -q -e ".[cameras]" || echo "rt2: camera drivers (rt2[cameras]) did not install here; their tests will be skipped"
	$(PY) -m pip install -q -e ".[cluster]" || echo "rt2: Ray (rt2[cluster]) did not install here; its tests will be skipped"
	$(PY) -m pip install -q -e ".[robots]" || echo "rt2: example-robot-data (rt2[robots]) did not install here; the panda, ur10 and xarm7 tests will be skipped"
	touch $(STAMP)

$(NODE_CLIENTS):
	if command -v npm >/dev/null; then npm install -q --no-audit --no-fund --prefix build/node @foxglove/ws-protocol-examples@0.10.0 \
	  || echo "rt2: npm could not install @foxglove/ws-protocol-examples; the live view's classic-client test will be skipped"; \
	else echo "rt2: npm is not installed; the live view's classic-client test will be skipped"; fi

demo: $(STAMP)
	$(VENV)/bin/rt2 demo

# The tests' disk cache of slow simulated-lab results (harness/common/disk_cache.py: the static lab's ray-cast, the
# launcher's flights), shared by the workers and the processes they start; empty in a fresh clone.
TEST_CACHE ?= $(CURDIR)/build/cache
# Tests marked `realtime` time live processes against the in-process run: they run alone, after the rest,
# so that the parallel suite does not take the cores they measure.
# A narrowed run (TESTS=...) may select no realtime test: pytest's "no tests ran" (exit 5) is no failure there.
# The parallel part names its 15 slowest tests at the end (the suite's time is kept well under 15 minutes on CI's 2 cores).
test: export RT2_CACHE_DIR = $(TEST_CACHE)
test: $(STAMP) $(NODE_CLIENTS)
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal -m "not slow and not realtime" --durations=15 $(call JUNIT_OPT,parallel) $(TESTS)
	$(PY) -m pytest -q -m "realtime and not slow" $(call JUNIT_OPT,realtime) $(TESTS); \
	  code=$$?; if [ -n "$(TESTS)" ] && [ $$code -eq 5 ]; then code=0; fi; exit $$code

# `make test` RUNS times in a row (default 5); lists every test that failed at least once, and the slowest 20.
# e.g. `make flaky RUNS=2 TESTS=tests/harness/common/test_progress.py` to try it on a subset.
# COLD=1 empties numba's kernel cache and the tests' disk cache before each run (`make clean-cache`): every run starts
# as a fresh clone's first.
COLD   ?=
flaky: $(STAMP)
	$(PY) tests/flaky_runs.py --runs $(RUNS) --tests "$(TESTS)" $(if $(COLD),--cold)

# The 20 slowest tests of `make test`'s parallel part (narrow with TESTS=...).
slowest: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal -m "not slow and not realtime" --durations=20 $(TESTS)

# How fast every long-running command stops on SIGINT / SIGTERM: TRIES per command and signal (default 20), beside
# `pytest -n 2` looping over LOAD (default tests/tracker; LOAD= for none); table on stdout, every try in
# build/stop_times.json; PARALLEL=N runs N tries at a time. e.g. `make stop-times TRIES=3 STOPS="play play-live"` (docs/reliability.md, "Stop times").
TRIES  ?= 20
LOAD   ?= tests/tracker
STOPS  ?=
PARALLEL ?= 1
stop-times: $(STAMP)
	$(PY) tests/stop_times.py --tries $(TRIES) --parallel $(PARALLEL) $(if $(LOAD),--load "$(LOAD)") $(if $(STOPS),--commands $(STOPS)) \
	  --json build/stop_times.json

# Long experiments marked `slow` (full studies); not part of `make test`.
test-all: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) -m "not realtime"
	$(PY) -m pytest -q -m "realtime"

bench: $(STAMP)
	$(VENV)/bin/rt2 bench estimator

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache

# Drop numba's disk cache (compiled kernels). Not needed after edits: each kernel's cache key holds the source
# of every jitted helper it compiles in (checks/numba_cache.py); this only frees the disk or times a cold start.
clean-numba:
	find tracker harness policies robot_models -name '*.nbi' -delete -o -name '*.nbc' -delete

# Drop every cache a fresh clone's first `make test` lacks: numba's kernels and the tests' disk cache (TEST_CACHE).
clean-cache: clean-numba
	rm -rf $(TEST_CACHE)
