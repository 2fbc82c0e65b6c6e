# maptidal: the two commands a new user needs are `make run` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.setup-stamp
RUN_DIR ?= runs/mission
# the tests run in this many processes (pytest-xdist): the machines have 2 cores, and the suite's heavy
# missions wait on each other's drawing; TEST_WORKERS=0 runs them in this one process. Each test module
# runs whole on one worker (--dist loadscope), so that a module's shared mission (a module-scoped
# fixture) is flown once, not once per worker that gets one of its tests. The modules go out in the
# order tests/conftest.py puts them, the slowest first (xdist's own reorder, by test count, sent the
# slowest module, which has few tests, out last, and one worker idled while it ran)
TEST_WORKERS ?= 2

# Headless rendering through EGL works on CPU-only machines (Mesa) and on NVIDIA GPUs.
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl

.PHONY: setup run test sitl-test bench golden lint clean

setup: $(STAMP)

# Idempotent: reinstalls only when the pins or the package metadata change.
$(STAMP): pyproject.toml requirements.lock envs/_hydro.c envs/_flight.c
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# the lock is complete (every dependency pinned), so it installs without resolving: MAVProxy declares
	# vtk, opencv-python and more for its GUI modules, which its console (all the tests use) does not need
	# and which would clash with opencv-python-headless
	# pip byte-compiles what it installs: keep it, since the tests' many processes would otherwise compile
	# every module they import, each time (PYTHONDONTWRITEBYTECODE keeps Python from caching them)
	$(BIN)/python -m pip install -q --no-deps -r requirements.lock
	$(BIN)/python -m pip install -q --no-deps -e .
	# compile the C hydrodynamics callback and flight stack (numpy and Python take over without a compiler)
	$(BIN)/python -c "from maptidal.envs.hydrodynamics import build_native; print('hydrodynamics library:', build_native())"
	$(BIN)/python -c "from maptidal.envs.native_flight import library; print('flight library:', getattr(library(), '_name', None))"
	touch $(STAMP)

run: setup
	$(BIN)/maptidal run --out $(RUN_DIR)

test: setup
	# our own modules compiled once: with PYTHONDONTWRITEBYTECODE set, each of the tests' many processes
	# would compile every one it imports, each time
	$(BIN)/python -m compileall -q maptidal envs controllers tests > /dev/null
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) $(if $(filter 0,$(TEST_WORKERS)),,--dist loadscope --no-loadscope-reorder)

# the tests against real ArduSub firmware: ARDUSUB_SITL=/path/to/ardusub make sitl-test (docs/mavlink.md, SITL)
sitl-test: setup
	@test -n "$$ARDUSUB_SITL" || { echo "set ARDUSUB_SITL to an ArduSub SITL binary (docs/mavlink.md: ArduSub SITL on our physics)"; exit 2; }
	$(BIN)/python -m pytest -q -m sitl

bench: setup
	$(BIN)/python tests/bench/bench_discovery.py
	$(BIN)/python tests/bench/bench_coverage.py
	$(BIN)/python tests/bench/bench_sim.py
	$(BIN)/python tests/bench/bench_allocation.py
	$(BIN)/python tests/bench/bench_gym.py
	$(BIN)/python tests/bench/bench_batched.py --envs 16 64
	$(BIN)/python tests/bench/bench_frontend.py
	$(BIN)/python tests/bench/bench_relocalisation.py
	$(BIN)/python tests/bench/bench_search.py
	$(BIN)/python tests/bench/bench_mission.py

# regenerate the front end's golden frames and outputs (tests/data/golden_frames) on purpose; prints what changed
golden: setup
	$(BIN)/python tests/data/make_golden.py

lint: setup
	$(BIN)/ruff check maptidal envs controllers tests
	$(BIN)/ruff format --check maptidal envs controllers tests

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis .ruff_cache *.egg-info
