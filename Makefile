# Two commands do all set-up on a fresh Debian machine:
#   make run    the daemon on its embedded default (mock hardware) on the PTY ./motorctl.pty
#   make test   the test suite (what .ci/run calls first)
#   make test-hw  the real-kernel tier: gpio-sim in QEMU guests, libgpiod v1 and v2 (hwtest/run;
#               builds its VM into ~/.cache/motorctl-gpio-sim on first use, as root)
# Each creates .venv from PyPI on first use (and installs python3-venv via apt when root and missing).
# The editable install filters setuptools' informational "Editable installation" note only: the
# checkout's motorctl/ folder (symlinks to the rooms) is meant to be importable; see pyproject.toml.

PYTHON ?= python3
VENV   ?= .venv
PTY    ?= $(CURDIR)/motorctl.pty
STATE  ?= $(CURDIR)/.run/state
JOBS   ?= 2
BIN     = $(VENV)/bin

.PHONY: run test test-hw lint bench coverage robustness clean venv

venv: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	@$(PYTHON) -c 'import ensurepip, venv' 2>/dev/null || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -q && apt-get install -y -q python3-venv; \
	  else echo "python3-venv is missing: run 'sudo apt-get install python3-venv'" >&2; exit 1; fi; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	PYTHONWARNINGS='ignore:Editable installation:UserWarning' $(BIN)/pip install -q -e '.[dev]'
	touch $@

run: venv
	$(BIN)/motorctld --pty $(PTY) --state-dir $(STATE) $(ARGS)

test: venv
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/pytest -q -n $(JOBS)

test-hw:
	hwtest/run all

# Unit coverage of the daemon's modules (the link, its session, state, service, status).
coverage: venv
	$(BIN)/pytest -q -n $(JOBS) --cov=motorctl.daemon --cov=motorctl.protocol.framing \
	  --cov-report=term-missing

# The robustness harness (docs/robustness.md): 10^6 frames, kill -9 cycles, HAL faults, soak.
# ARGS="--quick" for a short run; the full run takes about 20 minutes.
robustness: venv
	$(BIN)/python -m bench.robustness $(ARGS)

bench: venv
	$(BIN)/python bench/latency.py
	$(BIN)/python bench/steps.py

clean:
	rm -rf $(VENV) .run .pytest_cache .hypothesis .mypy_cache .ruff_cache *.egg-info
