# Two commands on a fresh machine: `make demo` and `make test` (both set everything up first).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.rt2-installed
# Foxglove's own node clients (the live view's tests run its classic client); skipped where npm is absent
NODE_CLIENTS := build/node/node_modules/.bin/ws-protocol-examples
JOBS   ?= 2

.PHONY: setup demo test test-all bench clean clean-numba

setup: $(STAMP) $(NODE_CLIENTS)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[train,test]"
	# camera drivers and Ray are optional extras; their tests run where they install, skip elsewhere
	$(PY) -m pip install -q -e ".[cameras]" || echo "rt2: camera drivers (rt2[cameras]) did not install here; their tests will be skipped"
	$(PY) -m pip install -q -e ".[cluster]" || echo "rt2: Ray (rt2[cluster]) did not install here; its tests will be skipped"
	touch $(STAMP)

$(NODE_CLIENTS):
	if command -v npm >/dev/null; then npm install -q --no-audit --no-fund --prefix build/node @foxglove/ws-protocol-examples@0.10.0 \
	  || echo "rt2: npm could not install @foxglove/ws-protocol-examples; the live view's classic-client test will be skipped"; \
	else echo "rt2: npm is not installed; the live view's classic-client test will be skipped"; fi

demo: $(STAMP)
	$(VENV)/bin/rt2 demo

# Tests marked `realtime` time live processes against the in-process run: they run alone, after the rest,
# so that the parallel suite does not take the cores they measure.
test: $(STAMP) $(NODE_CLIENTS)
	$(PY) -m pytest -q -n $(JOBS) -m "not slow and not realtime"
	$(PY) -m pytest -q -m "realtime and not slow"

# Long experiments marked `slow` (full studies); not part of `make test`.
test-all: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) -m "not realtime"
	$(PY) -m pytest -q -m "realtime"

bench: $(STAMP)
	$(VENV)/bin/rt2 bench estimator

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache

# numba's cache does not see edits to jitted helpers imported from another file (tracker/distortion.py)
clean-numba:
	find tracker harness policies -name '*.nbi' -delete -o -name '*.nbc' -delete
