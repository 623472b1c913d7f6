# hill_muscle_ros: the two commands are `make test` and `make demo`.
# Both set up .venv on first use (idempotent, fast the second time).

PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: test test-serial check-realtime check-install editable demo figures clean venv bytecode kernels interfaces

venv: $(STAMP) interfaces

# The venv's pip is brought to the pinned PIP_VERSION first: a Python 3.11's
# own pip may be old (Debian's is 23.0.1), and an old pip makes a legacy
# editable install that puts the console scripts where setup.cfg's
# ament_python script_dir says (lib/hill_muscle_ros), not in .venv/bin.
PIP_VERSION := 25.3

PIP_STAMP := $(VENV)/.pip-$(PIP_VERSION)

$(PIP_STAMP):
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --disable-pip-version-check -q pip==$(PIP_VERSION)
	touch $(PIP_STAMP)

# The package itself, editable, without its dependencies (test_install_clean,
# in `make check-install`, runs this target alone on the system's Python 3.11).
editable: $(PIP_STAMP)
	$(BIN)/python -m pip install --disable-pip-version-check -q --no-deps -e .

$(STAMP): $(PIP_STAMP) setup.py setup.cfg package.xml requirements-dev.txt requirements-ros.txt \
          hill_muscle_interfaces/requirements-build.txt
	$(BIN)/python -m pip install --disable-pip-version-check -q \
	    -r requirements-dev.txt -r requirements-ros.txt \
	    -r hill_muscle_interfaces/requirements-build.txt
	$(MAKE) editable
	touch $(STAMP)

# The package's bytecode, as pip writes it when it installs a package: the
# editable install compiles nothing ahead, and where PYTHONDONTWRITEBYTECODE is
# set (as on this machine) every process then compiled every module it
# imported from source, each node and CLI process the tests start included.
# compileall rewrites only the files changed since; Python reads the .pyc whatever
# that variable says, and ignores one older than its source.
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q hill_muscle_ros

# The message package hill_muscle_interfaces (ament_cmake, rosidl), built from
# the ROS 2 wheels and installed into the venv itself, so that it imports with
# no environment variable: about 25 s the first time, nothing once up to date
# (build.sh keeps a stamp of its sources and the wheels' versions). `colcon
# build` builds it too (hill_muscle_interfaces/README.md).
interfaces: $(STAMP)
	bash hill_muscle_interfaces/build.sh $(BIN) $(VENV)

# The model's numba kernels, compiled into numba's disk cache as the bytecode
# is (`hill-muscle compile`): about 45 s in a clean clone; under a second
# once cached. No node or test compiles after it.
kernels: $(STAMP) bytecode
	$(BIN)/hill-muscle compile

# `make test`: the behaviour, every test but the real-time claims, as two
# pytest runs side by side: the tests marked `ros`, which run nodes in real
# time, one module after the other (ROS_WORKERS), but for the `unpaced` ones
# (ROS_MARKS); the others (OFFLINE_MARKS) on TEST_WORKERS
# xdist workers (a module's tests on one worker, --dist loadscope), each
# worker on a ROS domain of its own, at nice 19 in a session whose autogroup
# is at nice 19 too (test/background_priority.py: any user may lower their
# own priority), so that they take the CPU the real-time runs leave idle.
# Two ROS workers and the offline run together kept the 2 cores busy:
# a simulator then stalled 0.2-0.7 s, its watchdog fired and a live run
# missed the offline force, in a run no faster (248 s) than one ROS worker.
# The offline run's report follows the ROS run's; either failing fails the
# target. A stop signal to make ends the offline run too, by SIGTERM: as a
# background job of a shell it ignores SIGINT, and in a session of its own a
# terminal's Ctrl-C does not reach it.
# `make test-serial`: the same tests, one after the other, in one run.
# `make check-realtime`: the claims on milliseconds of wall time (tests marked
# `realtime`), alone and serially, with a table of claim, measured and limit.
# `make check-install`: how the package installs (tests marked `install`): pip
# into a new venv, `make editable` on the system's Python 3.11, colcon build.
# Their pip installs and builds were a quarter of the offline tests' CPU (22 of
# 182 CPU-s) and the colcon build 3 s of the ROS run, for claims on the set-up,
# not on what the package does.
TEST_WORKERS ?= 2
ROS_WORKERS  ?= 1
# pytest caches its assertion-rewritten test modules as bytecode, but not
# where PYTHONDONTWRITEBYTECODE is set (as on this machine): each worker then
# rewrote every test module again, 5.5 CPU-s each.
PYTEST       := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest
PYTEST_TEST  := $(PYTEST) -q --dist loadscope --durations=15
# The ROS run collects the modules with a test marked `ros` (`-m` still picks
# the tests): importing every test module to read its markers took 4.3 CPU-s
# at the start of the run, the ROS modules 1.7.
ROS_TESTS = $(shell grep -l 'mark\.ros' test/test_*.py)
# The `ros` tests whose outcome no live run's pace decides (marked `unpaced`:
# start-up errors, parameters, messages) run with the offline tests: 8 s of the
# ROS run, which is the longer of the two.
ROS_MARKS     := ros and not unpaced
OFFLINE_MARKS := not ros or unpaced

test: $(STAMP) interfaces bytecode kernels
	@offline_log=$$(mktemp); \
	$(BIN)/python test/background_priority.py $(PYTEST_TEST) -n $(TEST_WORKERS) -m '$(OFFLINE_MARKS)' \
	    > $$offline_log 2>&1 & offline=$$!; \
	trap 'kill -TERM $$offline 2>/dev/null' INT TERM HUP; \
	echo "== the ROS tests (-m '$(ROS_MARKS)'); the others (-m '$(OFFLINE_MARKS)') run meanwhile, reported below"; \
	$(PYTEST_TEST) -n $(ROS_WORKERS) -m '$(ROS_MARKS)' $(ROS_TESTS); ros_status=$$?; \
	wait $$offline; offline_status=$$?; \
	echo "== the others (-m '$(OFFLINE_MARKS)')"; cat $$offline_log; rm -f $$offline_log; \
	test $$ros_status -eq 0 && test $$offline_status -eq 0

test-serial: $(STAMP) interfaces bytecode kernels
	$(PYTEST) -q -p no:xdist --durations=15

check-install: $(STAMP) interfaces bytecode kernels
	$(PYTEST) -q -p no:xdist -m install -rA $(shell grep -l 'mark\.install' test/test_*.py)

# The claims measure nodes as a user starts them, from their console scripts
# (HILL_MUSCLE_TEST_FORK=0), not forked from the tests' pre-loaded Python
# (test/node_zygote.py), whose memory a forked node shares until it writes it.
check-realtime: $(STAMP) interfaces bytecode kernels
	HILL_MUSCLE_TEST_FORK=0 $(PYTEST) -q -p no:xdist -m realtime -rA

# The live demo: simulator, protocol player and recorder as three ROS 2
# processes on a DDS domain of their own; the bag is read back, plotted
# (runs/<name>/force.png) and summarised. Options pass through:
#   make demo PROTOCOL=I UNITS=single LENGTH=instantaneous
#   make demo PROTOCOL=path/to/protocol.yaml
#   make demo RTF=10     # faster than real time, on sim time (/clock)
PROTOCOL ?= II
UNITS    ?=
LENGTH   ?=
RUNS_DIR ?= runs
RTF      ?=
demo: $(STAMP) bytecode
	$(BIN)/python -m hill_muscle_ros.demo --protocol '$(PROTOCOL)' \
	    --units '$(UNITS)' --length '$(LENGTH)' --runs-dir '$(RUNS_DIR)' \
	    $(if $(RTF),--real-time-factor '$(RTF)')

figures: $(STAMP) bytecode
	$(BIN)/hill-muscle figures --out runs/figures

# Benchmark (the performance targets in BENCHMARKS.md): installs the bench-only peers (pymuscle, MuJoCo,
# profilers) into .venv, profiles simulate() and writes BENCHMARKS.md.
# Takes a few minutes; never part of `make test`.
BENCH_STAMP := $(VENV)/.bench-installed

.PHONY: bench

$(BENCH_STAMP): $(STAMP) requirements-bench.txt
	$(BIN)/python -m pip install --disable-pip-version-check -q -r requirements-bench.txt
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP) bytecode
	$(BIN)/python benchmarks/profile_simulate.py
	$(BIN)/python benchmarks/run_all.py --out BENCHMARKS.md --runs 7

# The force controller closed around the simulator (doc/control.md, "Force controller"):
# a target profile through controller, simulator and recorder; a bag and a plot.
# PROFILE= a target-profile YAML (default config/target_profile.yaml), OUT= a new directory.
.PHONY: demo-closed-loop
demo-closed-loop: $(STAMP) bytecode
	$(BIN)/python -m hill_muscle_ros.demo_closed_loop $(if $(PROFILE),--profile $(PROFILE)) $(if $(OUT),--out $(OUT))

# The joint controller moves the simulated knee (doc/control.md, "make demo-knee"): limb node, joint
# controller and recorder on config/knee.yaml; angle steps and a sine; a bag, a plot
# and a stick-figure GIF. KNEE_PROFILE=short (8.5 s) for a quick look, brief (2.75 s) to try it, OUT= a new directory.
.PHONY: demo-knee
demo-knee: $(STAMP) bytecode
	$(BIN)/python -m hill_muscle_ros.demo_knee $(if $(KNEE_PROFILE),--profile $(KNEE_PROFILE)) $(if $(OUT),--out $(OUT))

clean:
	rm -rf $(VENV) build install log runs .pytest_cache .hypothesis *.egg-info
