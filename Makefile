# sabre — `make demo` and `make test` set everything up from a fresh clone.
#
# What goes into .venv comes from pyproject.toml: the published extras (through `maturin develop --extras`) and
# the development groups (`pip install --group`, PEP 735). Each set has its own stamp, so `make demo` after
# `make test` installs nothing and `make test` after `make demo` adds only what the tests need.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip install --quiet
MATURIN := $(VENV)/bin/maturin develop --release --quiet
export VIRTUAL_ENV := $(CURDIR)/$(VENV)

# the extras the tests exercise (the tests import them or skip without them)
TEST_EXTRAS := plot,viewer,meshes,experiments,mujoco,ros

BASE_STAMP := $(VENV)/.stamp-base
DEMO_STAMP := $(VENV)/.stamp-demo
TEST_STAMP := $(VENV)/.stamp-test
LINT_STAMP := $(VENV)/.stamp-lint
BENCH_STAMP := $(VENV)/.stamp-bench

.PHONY: all venv build demo test test-setup test-rust test-python test-ros-jazzy lint lint-rust lint-python lint-ruff lint-format lint-types \
	lint-length lint-cycles bench bench-rust bench-python clean

all: build

# The venv, a pip that reads dependency groups (25.1 or later) and maturin.
$(BASE_STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) "pip>=25.1"
	$(PIP) --group build
	touch $@

# The package (release build of the extension, editable) with the plot extra: all the demo needs.
$(DEMO_STAMP): $(BASE_STAMP)
	$(MATURIN) --extras plot
	touch $@

$(TEST_STAMP): $(DEMO_STAMP)
	$(PIP) --group test
	$(MATURIN) --extras $(TEST_EXTRAS)
	touch $@

$(LINT_STAMP): $(BASE_STAMP)
	$(PIP) --group lint
	touch $@

$(BENCH_STAMP): $(BASE_STAMP)
	$(PIP) --group bench
	touch $@

venv: $(BASE_STAMP)

# Rebuilds the extension in place after a change to the Rust code (the editable install is the stamp's).
build: $(DEMO_STAMP)
	$(MATURIN) --skip-install

demo: build
	$(PY) -m sabre demo

test-rust:
	cargo test --profile quick-release

# The browser test drives Debian's chromium through Playwright (never `playwright install`);
# urdfdom's check_urdf checks that the shipped URDFs are standard.
test-setup:
	(command -v chromium && command -v check_urdf) >/dev/null || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium liburdfdom-tools)

test-python: $(TEST_STAMP) build test-setup
	$(PY) -m pytest -q tests

# The Rust tests build while the test environment installs; the Python tests run after both, with the
# machine to themselves (some start ROS 2 nodes that keep a 1 kHz loop).
test:
	$(MAKE) -j2 --output-sync=target test-rust $(TEST_STAMP)
	$(MAKE) test-python

# The ROS 2 bridge's tests under Jazzy (`make test` runs them under Kilted, the `ros` extra): a venv of its own,
# since the two distributions' wheels install the same module names.
# `meshes` brings the example robots the fixed-base test drives.
JAZZY_VENV := .venv-jazzy
test-ros-jazzy: $(BASE_STAMP)
	test -x $(JAZZY_VENV)/bin/python || $(PYTHON) -m venv $(JAZZY_VENV)
	$(JAZZY_VENV)/bin/python -m pip install --quiet "pip>=25.1" pytest
	$(JAZZY_VENV)/bin/python -m pip install --quiet --group build
	VIRTUAL_ENV=$(CURDIR)/$(JAZZY_VENV) $(JAZZY_VENV)/bin/maturin develop --release --quiet --extras ros-jazzy,meshes
	$(JAZZY_VENV)/bin/python -m pytest -q tests/ros

# `make -k lint` reports every tool's findings instead of stopping at the first.
# clippy with the python feature builds PyO3 against the venv's interpreter.
# sabre-rcl twice: with the ROS 2 headers it finds (its layouts) and without any (what a build without ROS gets).
lint-rust: $(BASE_STAMP)
	cargo fmt --all --check
	cargo clippy --all-targets -- -D warnings
	cargo clippy --all-targets --features python -- -D warnings
	cargo clippy -p sabre-rcl --all-targets -- -D warnings
	SABRE_ROS_PREFIX=none cargo clippy -p sabre-rcl --all-targets -- -D warnings

lint-ruff: $(LINT_STAMP)
	$(VENV)/bin/ruff check .

lint-format: $(LINT_STAMP)
	$(VENV)/bin/ruff format --check .

# mypy reads the plot extra's types (the demo stamp); the stub check compares python/sabre/_core.pyi with the
# built extension.
lint-types: $(LINT_STAMP) build
	$(PY) -m mypy python/sabre
	$(PY) -m mypy.stubtest sabre._core

# python/sabre's functions stay within 80 lines unless a `# long:` comment says why.
lint-length: $(BASE_STAMP)
	$(PY) tools/function_length.py python/sabre

lint-python: lint-ruff lint-format lint-types lint-length

# No two modules of the Rust crate or of python/sabre import each other, directly or around a circle (imports
# under `if TYPE_CHECKING:` count); the tool's first lines say what counts as an import.
lint-cycles: $(BASE_STAMP)
	$(PY) tools/module_cycles.py src python/sabre

lint: lint-rust lint-python lint-cycles

bench-rust:
	cargo bench --bench rollout
	cargo bench --bench planning
	cargo bench --bench safety

bench-python: $(BENCH_STAMP) build
	$(PY) benches/compare_mujoco.py
	$(PY) benches/compare_planning.py
	$(PY) benches/compare_osqp.py

bench: bench-rust bench-python

clean:
	cargo clean
	rm -rf $(VENV) $(JAZZY_VENV) .pytest_cache
