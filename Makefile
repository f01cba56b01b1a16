# sabre — `make demo` and `make test` set everything up from a fresh clone.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.deps-stamp
export VIRTUAL_ENV := $(CURDIR)/$(VENV)

.PHONY: all venv build demo test test-setup test-rust test-python lint lint-rust lint-python bench bench-rust bench-python clean

all: build

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "maturin>=1.5,<2" "numpy>=1.24" "pytest>=7" "matplotlib>=3.7" "tqdm>=4.60" "mujoco>=3.1" "osqp>=0.6" \
		"ruff>=0.5" "mypy>=1.10" \
		"viser>=1.0" "trimesh>=4" "pycollada>=0.8" "example-robot-data>=4" "playwright>=1.40" "ray>=2.9" "hypothesis>=6.100" "pin>=3"
	$(PY) -m pip install --quiet "ros-rclpy>=9.1" "ros-rmw-fastrtps-cpp>=9.3" "ros-sensor-msgs>=5.5" "ros-geometry-msgs>=5.5" "ros-std-msgs>=5.5" "ros-diagnostic-msgs>=5.5" "ros-rosgraph-msgs>=2.3" "hdrhistogram>=0.10" "threadpoolctl>=3.1"
	touch $(STAMP)

venv: $(STAMP)

# Release build of the extension, installed into the venv in editable mode.
build: venv
	$(VENV)/bin/maturin develop --release --quiet

demo: build
	$(PY) -m sabre demo

test-rust:
	cargo test --release

# The browser test drives Debian's chromium through Playwright (never `playwright install`);
# urdfdom's check_urdf checks that the shipped URDFs are standard.
test-setup:
	(command -v chromium && command -v check_urdf) >/dev/null || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium liburdfdom-tools)

test-python: build test-setup
	$(PY) -m pytest -q tests

test: test-rust test-python

# `make -k lint` reports every tool's findings instead of stopping at the first.
lint-rust: venv
	cargo fmt --check
	cargo clippy --all-targets -- -D warnings
	cargo clippy --all-targets --features python -- -D warnings

# The stub check compares python/sabre/_core.pyi with the built extension.
lint-python: build
	$(VENV)/bin/ruff check .
	$(PY) -m mypy python/sabre
	$(PY) -m mypy.stubtest sabre._core

lint: lint-rust lint-python

bench-rust:
	cargo bench --bench rollout
	cargo bench --bench planning
	cargo bench --bench safety

bench-python: build
	$(PY) benches/compare_mujoco.py
	$(PY) benches/compare_planning.py
	$(PY) benches/compare_osqp.py

bench: bench-rust bench-python

clean:
	cargo clean
	rm -rf $(VENV) .pytest_cache
