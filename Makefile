# hydropump: `make demo` runs the main job (the paper end to end through the ROS 2 nodes),
# `make test` runs lint and the tests.
# Both bootstrap .venv on first use (Python 3.11, everything pinned in requirements.txt).

PYTHON ?= python3
# apt-get as root, else through sudo.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.hydropump-installed
PKGS := hydropump_sim hydropump_ctrl ros_pkgs/hydropump_ros
SETUP_FILES := requirements.txt $(foreach p,$(PKGS) ros_pkgs/hydropump_bringup,$(p)/setup.py \
	$(p)/package.xml)

export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: all demo test lint bench soak clean

all: demo

$(STAMP): $(SETUP_FILES)
	# Chromium for the report's browser test (Debian's package: Playwright's own browser
	# download is not reachable everywhere); the test says so and skips where it is absent.
	command -v chromium > /dev/null || { $(SUDO) apt-get install -y -q chromium \
		|| { $(SUDO) apt-get update -q && $(SUDO) apt-get install -y -q chromium; } \
		|| echo 'warning: chromium not installed: the report browser test will skip'; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip==25.3
	$(BIN)/python -m pip install --quiet -r requirements.txt
	$(BIN)/python -m pip install --quiet --no-build-isolation --no-deps \
		--config-settings editable_mode=compat \
		$(foreach p,$(PKGS),-e $(p))
	$(BIN)/python -m hydropump_ros.venv_index --root . > /dev/null
	# Compile the plant and the shipped circuits once (numba caches them on disk).
	$(BIN)/python -m hydropump_sim.warm
	touch $@

demo: $(STAMP)
	$(BIN)/hydropump-demo

lint: $(STAMP)
	$(BIN)/ruff check .

# pytest exits with 5 when it collects no tests; that is not a failure of the suite.
# Two workers, each taking a whole test file at a time (module fixtures are built once):
# many tests wait on node processes and DDS, so two files run side by side on two cores.
test: lint
	$(BIN)/python -m pytest -n 2 --dist loadfile; rc=$$?; [ $$rc -eq 5 ] && rc=0; exit $$rc

# Every benchmark, then the table of bench/README.md from bench/results.json.
bench: $(STAMP)
	$(BIN)/python bench/run_all.py
	$(BIN)/python docs/generate_tables.py

# The seam tests at full length: ten Ctrl-C / SIGTERM loops per node, twenty lock-step runs
# with a frozen recorder and twenty with both cores loaded (about ten minutes).
soak: $(STAMP)
	HYDROPUMP_SIGNAL_LOOPS=10 HYDROPUMP_SOAK=20 $(BIN)/python -m pytest -q \
		tests/ros/test_seams.py::test_every_node_ends_cleanly_on_ctrl_c_twice_and_sigterm \
		tests/ros/test_recorder.py -k 'ctrl_c or bit_identical'
	# The nodes and the main job with every core kept busy (a shared CI machine).
	$(BIN)/python tests/loaded.py -- $(BIN)/python -m pytest -q -n 2 --dist loadfile \
		tests/ros tests/e2e

clean:
	rm -rf $(VENV) build install log out
