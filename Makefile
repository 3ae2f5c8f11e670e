# Two commands set everything up on a fresh machine:
#   make demo   installs colonlight into .venv and runs the main job on an embedded synthetic clip
#   make test   installs colonlight with its test tools into .venv, runs the lint and type gates, then the test suite
# TORCH_SPEC picks the torch build; the default is whatever the package index gives (PyPI: the CUDA build on
# Linux x86-64, several GB). The CPU build:
#   make demo TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"

PYTHON     ?= python3
VENV       ?= .venv
TORCH_SPEC ?= torch==2.13.0
BIN        := $(VENV)/bin

.PHONY: demo test lint install install-test browser cpp-host benchmark figures clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# EXTRAS adds optional extras to `make install`/`make demo`, e.g. EXTRAS=eval or EXTRAS=eval,cluster,export,docs
# (`make install-test` has all of them: the test extra includes their packages).
EXTRAS     ?=

install: $(BIN)/python
	$(BIN)/pip install --quiet $(TORCH_SPEC)
	$(BIN)/pip install --quiet -e ".$(if $(EXTRAS),[$(EXTRAS)])"

install-test: $(BIN)/python browser
	$(BIN)/pip install --quiet $(TORCH_SPEC)
	$(BIN)/pip install --quiet -e ".[test]"
	@$(MAKE) --no-print-directory cpp-host

# The web page's test drives Debian's chromium; installed when possible (root with apt), else that test skips.
browser:
	@if [ ! -x /usr/bin/chromium ] && [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		(apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
		|| echo "note: chromium could not be installed; the browser test will skip"; fi

# The C++ host's test builds examples/cpp_host: g++, OpenCV's imgproc and nlohmann-json (Debian's packages, when
# root with apt) and ONNX Runtime's headers (fetched by its Makefile); what cannot be had makes that test skip.
cpp-host:
	@if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then $(MAKE) -s -C examples/cpp_host deps \
		|| echo "note: the C++ host's dependencies could not be installed; its test will skip"; \
	else $(MAKE) -s -C examples/cpp_host headers || echo "note: no ONNX Runtime headers; the C++ host's test will skip"; fi

demo: install
	$(BIN)/colonlight demo

# The gates before the suite, each failing `make test` on any finding: ruff's lint and format over the whole tree,
# mypy strict on the engine, the CLI and the service (colonlight/, cli/, service/; configured in pyproject.toml).
lint: install-test
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# TEST_WORKERS=2 runs the suite in two processes (pytest-xdist), a test file's tests all in one of them, so that a
# file's own loopback ports and module fixtures (a cluster, a server) are never shared: about 9 minutes instead of
# 15 on 2 cores. One process stays the default: two squeeze the suite's timing-sensitive tests on 2 cores.
TEST_WORKERS ?= 0

test: lint
	$(BIN)/python -m pytest --numprocesses $(TEST_WORKERS) --dist loadfile

benchmark: install-test
	$(BIN)/python -m benchmarks

# The README's pictures, from the shipped default model: the before/after strip and gamma plot, the evaluation
# plots (from a fresh `colonlight evaluate` report on held-out synthetic clips) and the web page's screenshot.
FIGURES_EVAL ?= build/figures-eval
figures: install-test
	$(BIN)/python scripts/make_figures.py
	$(BIN)/colonlight evaluate --synthetic 4 --family heldout --frames 48 --size 160 --no-colmap \
		--methods none,he,deflicker,rnn -o $(FIGURES_EVAL)
	$(BIN)/python scripts/report_figures.py $(FIGURES_EVAL)/report.html docs
	COLONLIGHT_UPDATE_SCREENSHOT=1 $(BIN)/python -m pytest -q tests/service/test_service_browser.py

clean:
	rm -rf $(VENV) colonlight-demo build *.egg-info
