# lip_ros: set-up, demo and tests on a Debian machine with Python 3.11.
#   make demo   create/reuse .venv, install, run the main job on the bundled demo bag
#   make test   create/reuse .venv, install, lint (ruff), run the whole test suite
#   make demo-hsc4d  the HSC4D graph on a rig capture made on first use (hip LiDAR + suit)

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
INSTALLED := $(VENV)/.installed
OUT ?= out
# make test: pytest-xdist workers (each in a ROS domain of its own; test/conftest.py)
TEST_WORKERS ?= 2

# Keep DDS on this machine's loopback, in a domain of its own per run.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
ROS_DOMAIN_ID ?= $(shell $(PYTHON) -c 'import random; print(random.randint(1, 100))')
export ROS_DOMAIN_ID

.PHONY: venv kernels demo demo-bag demo-hsc4d test bench urdf clean clean-shm

venv: $(INSTALLED)

$(INSTALLED): setup.py setup.cfg pyproject.toml package.xml
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 10), "Python >= 3.10 needed"'
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || { echo "python venv failed: apt-get install python3-venv"; exit 1; }
	$(PY) -m pip install --quiet -e ".[pypi,test]"
	@touch $@

# numba compiles the package's hot loops (lip_ros.core.compiled lists them) when their modules are first imported
# and caches them beside the sources: some seconds after an install or a change to them, then a fraction of a
# second. Done here once, before the test workers and nodes import them (a colcon install elsewhere, as the
# install-layout test's, fills its own cache on its first import).
kernels: $(INSTALLED)
	@$(PY) -c 'import lip_ros.lip.surface_fit, lip_ros.lip.segmentation.clusters'

demo: kernels
	rm -rf $(OUT)/demo_walk $(OUT)/demo_walk_calibration.yaml
	$(VENV)/bin/lip_process_bag bags/demo_walk $(OUT)/demo_walk --plot $(OUT)/demo_walk.png

# The HSC4D demo capture: 30 s of the rig's seed 3 (A-pose, jump, a walk over stairs), made deterministically on
# first use (about a minute; some 280 MB, too big for bags/), then reused.
HSC4D_DEMO := $(OUT)/hsc4d_demo_capture

$(HSC4D_DEMO)/metadata.yaml: | $(INSTALLED)
	rm -rf $(HSC4D_DEMO)
	$(VENV)/bin/lip_rig site-bag --seed 3 --seconds 30 --out $(HSC4D_DEMO)

demo-hsc4d: kernels $(HSC4D_DEMO)/metadata.yaml
	rm -rf $(OUT)/hsc4d_demo $(OUT)/hsc4d_demo_refined
	$(VENV)/bin/lip_process_bag $(HSC4D_DEMO) $(OUT)/hsc4d_demo --plot $(OUT)/hsc4d_demo.png --refine

# Regenerate the bundled demo bag (command documented in bags/README.md).
demo-bag: $(INSTALLED)
	rm -rf bags/demo_walk
	$(VENV)/bin/lip_rig make-bag --scenario walk --seconds 13 --seed 1 --distance 6 --columns 512 \
		--azimuth-window 150 210 --out bags/demo_walk

test: kernels
	$(VENV)/bin/ruff check .
	$(PY) -m pytest test -q -p no:cacheprovider -n $(TEST_WORKERS) --durations=30

bench: $(INSTALLED)
	$(PY) benchmarks/bench_msgs.py
	$(PY) benchmarks/bench_rig_lidar.py
	$(PY) benchmarks/bench_dds_clouds.py

urdf: $(INSTALLED)
	$(PY) -m lip_ros.tools.make_urdf

# Fast DDS shared memory left by ROS processes that were killed or crashed (segments no live process holds).
clean-shm: $(INSTALLED)
	$(PY) -c 'from lip_ros.middleware import remove_stale_shm; print(f"removed {len(remove_stale_shm())} files")'

clean:
	rm -rf $(VENV) $(OUT) build install log .pytest_cache
