# tripod: two commands on a fresh Debian machine.
#   make demo   set everything up, then run the main job on the bundled defaults
#   make test   set everything up, then run all tests
# Both are fast when nothing changed (stamps under .venv/).
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check -q
# this machine's pip config names index folders that may not exist: hide that noise only
QUIET := 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
SHARED_DATA ?= ../shared/data
DEMO_DIR ?= demo-output

SYSTEM_STAMP := $(VENV)/.stamp-system
DEPS_STAMP := $(VENV)/.stamp-deps
INSTALL_STAMP := $(VENV)/.stamp-install
PYPROJECTS := shared/pyproject.toml daemon/pyproject.toml processor/pyproject.toml

.PHONY: all setup test demo bench bench-quick stubs clean distclean

all: setup

$(SYSTEM_STAMP): scripts/ensure-system-deps.sh
	@PYTHON=$(PYTHON) scripts/ensure-system-deps.sh
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@touch $@

# Heavy third-party wheels first (torch from the provided CPU wheel), then our packages.
$(DEPS_STAMP): $(SYSTEM_STAMP) requirements-dev.txt
	@echo "tripod: installing Python dependencies into $(VENV) (first run takes a few minutes)"
	$(PIP) install --upgrade pip setuptools wheel $(QUIET)
	$(PIP) install "torch==2.13.0" $(QUIET)
	$(PIP) install -r requirements-dev.txt $(QUIET)
	@touch $@

# The editable installs map each package's files when installed: a module added or removed
# (a pull, a merge) needs a reinstall, so the list of source files is part of the stamp.
SOURCES_HASH := $(shell find shared/src daemon/src processor/src -name '*.py' | sort | md5sum | cut -c1-12)
SOURCES_STAMP := $(VENV)/.stamp-sources-$(SOURCES_HASH)

$(SOURCES_STAMP):
	@mkdir -p $(VENV) && rm -f $(VENV)/.stamp-sources-* && touch $@

$(INSTALL_STAMP): $(DEPS_STAMP) $(PYPROJECTS) $(SOURCES_STAMP)
	@echo "tripod: installing shared, daemon and processor (building the C++ extension)"
	$(PIP) install -e shared -e "daemon[panel]" $(QUIET)
	$(PIP) install --no-build-isolation -e processor \
		--config-settings=cmake.define.TRIPOD_BUILD_TESTS=ON $(QUIET)
	@touch $@

setup: $(INSTALL_STAMP)

test: setup
	$(PY) -m pytest

demo: setup
	$(VENV)/bin/tripod demo -o $(DEMO_DIR)

# Every bench, each to the end with its defaults (a long run: about an hour and a half on 2 cores,
# most of it bench/scene.py, bench/reconstruct.py and bench/rigs.py); bench-quick runs each with --quick (a smoke run
# of a few minutes: fewer scenes, repeats and pairs; its numbers are not the README's).
BENCH_ARGS ?=
bench: setup
	$(PIP) install -e "processor[bench]" --no-build-isolation
	@for b in bench/*.py; do echo "== $$b $(BENCH_ARGS)"; $(PY) $$b $(BENCH_ARGS) || exit 1; done

bench-quick:
	@$(MAKE) --no-print-directory bench BENCH_ARGS=--quick

# Refresh the committed type stubs of the C++ extension (tests/processor/test_stubs.py checks them).
stubs: setup
	$(PY) -m nanobind.stubgen -q -P -m tripod_processor._ext -o processor/src/tripod_processor/_ext.pyi

clean:
	rm -rf processor/build $(DEMO_DIR) .pytest_cache

distclean: clean
	rm -rf $(VENV)
