# SPEED+ builder. Quick start on a fresh machine: `make dataset`, `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_STAMP := $(VENV)/.installed-run
PROFILE ?= default
WORKSPACE ?= data/$(PROFILE)

.PHONY: setup dataset test bench lint clean

# The package's bytecode, compiled ahead: where PYTHONDONTWRITEBYTECODE is set (as on the
# machines this is built on) every process compiled its ~180 modules from source again,
# 0.38 s of each `speedplus` command and of each local worker a run spawns (docs/development.md).
# Python checks each .pyc against its source, so an edit after this is still what runs.
COMPILE := $(BIN)/python -m compileall -q core pipeline stages manifests speedplus bench

# setup: everything the tests need (dev tools, the [cluster] extra: Ray, Debian chromium for
# the report test); `make dataset` installs only what a local run needs (libllvm19, the package).
setup: $(STAMP)

$(STAMP): $(RUN_STAMP)
	@if [ "$$(id -u)" = "0" ] && ! command -v chromium >/dev/null; then \
		echo "installing Debian chromium (the report test renders the HTML page headless)"; \
		apt-get install -y chromium >/dev/null 2>&1 || echo "warning: chromium not installed; the report test fails"; \
	fi
	$(BIN)/pip install --quiet -e '.[dev,cluster]'
	touch $(STAMP)

# Mitsuba's fast llvm variant needs libLLVM >= 16; Debian 12 ships 14/15 by default.
$(RUN_STAMP): pyproject.toml
	@if [ "$$(id -u)" = "0" ] && ! ldconfig -p | grep -q 'libLLVM.so.19'; then \
		echo "installing Debian libllvm19 for Mitsuba's llvm variant"; \
		(apt-get install -y libllvm19 >/dev/null 2>&1 || \
		 (apt-get update >/dev/null && apt-get install -y libllvm19 >/dev/null)) || \
		echo "warning: libllvm19 not installed; rendering (acquire, render) will refuse to run"; \
	fi
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $(RUN_STAMP)

dataset: $(RUN_STAMP)
	$(COMPILE)
	$(BIN)/speedplus run --profile $(PROFILE) --workspace $(WORKSPACE)
	$(BIN)/speedplus export --workspace $(WORKSPACE) --format speedplus
	@echo "report:  $(WORKSPACE)/report/index.html"
	@echo "exports: $(WORKSPACE)/export/speedplus (SPEED+ layout); manifests: $(WORKSPACE)/manifests"

test: setup
	$(BIN)/ruff check core pipeline stages manifests speedplus tests bench
	$(COMPILE)
	$(BIN)/python -m pytest -q -n auto --dist loadfile --durations=15

bench: setup
	$(BIN)/python -m bench

lint: setup
	$(BIN)/ruff check core pipeline stages manifests speedplus tests bench

clean:
	rm -rf $(VENV) data
