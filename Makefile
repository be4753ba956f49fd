# Two commands on a fresh machine (Python 3 + pip): `make demo`, `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
PY     := $(BIN)/python

# What ROS 2 needs in the venv route: the ament index of this venv (so
# get_package_share_directory('subpix_ros') finds share/subpix_ros), Fast DDS,
# and discovery kept on this machine unless the user configures otherwise.
PREFIX := $(CURDIR)/$(VENV)/subpix_prefix
export AMENT_PREFIX_PATH := $(PREFIX):$(CURDIR)/$(VENV)$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONUNBUFFERED := 1

.PHONY: all venv sample browser demo test bench clean
all: test

$(VENV)/.installed: requirements.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	# An editable install does not place data_files: index the package and its
	# share directory (package.xml, config/, data/) by links into this checkout.
	mkdir -p $(PREFIX)/share/ament_index/resource_index/packages $(PREFIX)/share/subpix_ros
	ln -sfn $(CURDIR)/resource/subpix_ros $(PREFIX)/share/ament_index/resource_index/packages/subpix_ros
	ln -sfn $(CURDIR)/package.xml $(PREFIX)/share/subpix_ros/package.xml
	ln -sfn $(CURDIR)/config $(PREFIX)/share/subpix_ros/config
	ln -sfn $(CURDIR)/data $(PREFIX)/share/subpix_ros/data
	touch $@

venv: $(VENV)/.installed

# The sample flights (rosbag2, mcap), built reproducibly from the bundled real frames.
data/bags/.built: $(VENV)/.installed scripts/build_sample_flight.py data/seneca/frames.csv
	$(PY) scripts/build_sample_flight.py --out data/bags
	touch $@

sample: data/bags/.built

demo: sample
	$(BIN)/subpix demo --out out/demo

# Debian's chromium for the flight report's browser test (test/process/test_report_browser.py):
# installed when missing (as root, or through sudo without a password), otherwise a clear error.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then SUDO=; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; else \
	    echo "make: chromium is missing and cannot be installed without root: apt-get install chromium" >&2; \
	    exit 1; fi; \
	  echo "installing chromium (Debian package) for the report test"; \
	  $$SUDO apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null; }
	@command -v chromium >/dev/null 2>&1

test: sample browser
	$(PY) -m pytest test

bench: sample
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) data/bags out build install log
