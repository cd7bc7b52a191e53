# One-command set-up and the two entry points of the README: `make demo` and `make test`.
# Set-up is incremental: each step leaves a stamp in .venv only when it succeeded, so a failed
# download or build is resumed by the next `make` instead of leaving a half-built venv.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
BUILD := build/msg_defs
MSGS := $(wildcard msg_defs/msg/*.msg msg_defs/srv/*.srv)

.PHONY: setup foxglove demo test test-fast lint bench clean check-tools
.DEFAULT_GOAL := demo

setup: $(VENV)/.stamp-package foxglove

# Foxglove's own JavaScript readers (@mcap/core, @foxglove/rosmsg2-serialization), pinned in
# test/foxglove/package-lock.json, for the test that reads our bags as Foxglove does; without
# npm that test skips and says so.
foxglove: test/foxglove/node_modules/.stamp
test/foxglove/node_modules/.stamp: test/foxglove/package-lock.json
	@if command -v npm >/dev/null 2>&1; then \
	  echo '[setup] installing Foxglove readers for the bag tests (npm ci)'; \
	  npm ci --prefix test/foxglove --no-audit --no-fund --silent && touch $@ \
	  || { echo 'set-up failed: npm ci in test/foxglove'; exit 1; }; \
	else echo 'set-up: npm not found; the Foxglove reader test will skip'; fi

check-tools:
	@command -v $(PYTHON) >/dev/null || { echo 'set-up: $(PYTHON) is missing (need Python 3.11 with venv)'; exit 1; }
	@command -v cmake >/dev/null || { echo 'set-up: cmake is missing (apt-get install cmake)'; exit 1; }
	@command -v cc >/dev/null || command -v gcc >/dev/null || { echo 'set-up: no C compiler (apt-get install gcc g++)'; exit 1; }
	@command -v c++ >/dev/null || command -v g++ >/dev/null || { echo 'set-up: no C++ compiler (apt-get install g++)'; exit 1; }

$(VENV)/.stamp-venv: | check-tools
	@echo '[setup 1/4] creating $(VENV)'
	@$(PYTHON) -m venv $(VENV) || { rm -rf $(VENV); echo 'set-up failed at step 1/4: python -m venv'; exit 1; }
	@touch $@

$(VENV)/.stamp-deps: $(VENV)/.stamp-venv requirements.txt requirements-build.txt requirements-dev.txt constraints.txt
	@echo '[setup 2/4] installing ROS 2 wheels and Python packages (about 35 s)'
	@$(BIN)/pip install -q --disable-pip-version-check -r requirements.txt -r requirements-build.txt -r requirements-dev.txt \
	  || { echo 'set-up failed at step 2/4: pip install (run make again to resume)'; exit 1; }
	@touch $@

$(VENV)/.stamp-msgs: $(VENV)/.stamp-deps msg_defs/CMakeLists.txt msg_defs/package.xml $(MSGS) | check-tools
	@echo '[setup 3/4] building msg_defs (microball_msgs) with rosidl'
	@mkdir -p $(BUILD) && PATH=$(CURDIR)/$(BIN):$$PATH LD_LIBRARY_PATH=$(CURDIR)/$(VENV)/lib \
	  cmake -S msg_defs -B $(BUILD) -DCMAKE_PREFIX_PATH=$(CURDIR)/$(VENV) \
	  -DCMAKE_INSTALL_PREFIX=$(CURDIR)/$(VENV) -DPython3_EXECUTABLE=$(CURDIR)/$(BIN)/python \
	  -DBUILD_TESTING=OFF >$(BUILD).log 2>&1 \
	  && PATH=$(CURDIR)/$(BIN):$$PATH LD_LIBRARY_PATH=$(CURDIR)/$(VENV)/lib \
	  cmake --build $(BUILD) -j2 >>$(BUILD).log 2>&1 \
	  && cmake --install $(BUILD) >>$(BUILD).log 2>&1 \
	  || { echo "set-up failed at step 3/4: building msg_defs (log: $(BUILD).log)"; exit 1; }
	@touch $@

$(VENV)/.stamp-package: $(VENV)/.stamp-msgs setup.py setup.cfg
	@echo '[setup 4/4] installing microball_ros (editable)'
	@$(BIN)/pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e . \
	  || { echo 'set-up failed at step 4/4: pip install -e .'; exit 1; }
	@touch $@

demo: setup
	$(BIN)/microball experiment --scenario paper --duration 40 --speed 1.5

test: setup
	$(BIN)/python -m pytest

# The fast tier: core numerics and io (CSV, bags, fingerprint), no DDS (about 30 s).
FAST_TESTS := $(wildcard test/test_core_*.py test/test_io_*.py) test/test_records.py \
	test/test_bags_io.py test/test_layers.py
test-fast: setup
	$(BIN)/python -m pytest -m 'not ros' $(FAST_TESTS)

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: setup
	$(BIN)/pip install -q --disable-pip-version-check -r requirements-bench.txt
	$(BIN)/python bench/bench_estimation.py
	$(BIN)/python bench/bench_tracking.py
	$(BIN)/python bench/bench_nodes.py
	$(BIN)/python bench/bench_bags.py

clean:
	rm -rf $(VENV) build *.egg-info
