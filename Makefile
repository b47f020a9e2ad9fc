# Two commands do all set-up on a fresh Debian machine:
#   make run    the daemon on its embedded default (mock hardware) on the PTY ./motorctl.pty
#   make test   the test suite (what .ci/run calls first)
#   make test-slow  the tests marked slow, which make test leaves out (.ci/run runs them next)
#   make test-dspin  the conformance suite against motorctld on docs/examples/dspin.toml's mock
#               dSPIN chips instead of the embedded default's STEP/DIR motors (.ci/run: after make test)
#   make test-hw  the real-kernel tier: gpio-sim in QEMU guests, libgpiod v1 and v2 (hwtest/run;
#               builds its VM on first use, as root, into $XDG_CACHE_HOME/motorctl-gpio-sim,
#               ~/.cache/motorctl-gpio-sim without it, $MOTORCTL_GSIM_CACHE if set; the folder
#               is made when missing; built again when its recipe changes or Debian's archive
#               offers another kernel tuple than it was built from, printed each run; in the
#               guests a skipped test fails)
# Each creates .venv from PyPI on first use (and installs python3-venv via apt when root and missing).
# The venv's install builds the compiled step core (setup.py: motion/executors/csrc/ ->
# motion/executors/_stepcore*.so, in place); that needs gcc and the Python headers, installed
# via apt (gcc, python3-dev) when root and missing. make stepcore rebuilds it after a change to
# its sources (make test and make run do); make test-asan runs the core's tests on a build
# with the address and undefined-behaviour sanitizers.
# make test also installs socat via apt when root and missing (the serial device reconnect tests
# tear a socat PTY pair down and make it again; without socat they skip, saying so loudly), and
# tshark the same way (the Wireshark dissector's tests; without it they skip, saying so loudly),
# quietly: one line each, apt's output only when it fails. It never installs Debian's
# prometheus server for its promtool: the metrics are linted by promtool's rules in Python,
# and by promtool itself where it is installed already and in make test-deb.
# The editable install filters setuptools' informational "Editable installation" note only: the
# checkout's motorctl/ folder (symlinks to the rooms) is meant to be importable; see pyproject.toml.

PYTHON ?= python3
VENV   ?= .venv
PTY    ?= $(CURDIR)/motorctl.pty
STATE  ?= $(CURDIR)/.run/state
JOBS   ?= 2
# make test's pytest workers: one more than the 2 cores, as its tests wait on real-time motion
# and on their daemons much of the time (at -n 2 the machine's 2 cores were 55-65 % busy);
# docs/timing.md, "make test's time". TEST_JOBS=2 for the earlier count.
TEST_JOBS ?= 3
BIN     = $(VENV)/bin

.PHONY: run test test-slow test-dspin test-hw lint bench coverage robustness clean venv deb deb-deps test-deb test-deps \
  test-root stepcore test-asan dataclass-code

venv: $(VENV)/.installed

# apt_quiet WHAT WHY PACKAGE...: what the make targets install from Debian when root and it is
# missing, quietly: one line says which and why, apt's output goes to a temporary log that is
# shown (its last 20 lines) only when the install fails.
APT_QUIET = apt_quiet() { \
  log=$$(mktemp) && echo "make: installing $$1 with apt-get (as root: $$2)" && shift 2 && \
  { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q \
      -o DPkg::Lock::Timeout=600 --no-install-recommends "$$@"; } > "$$log" 2>&1; \
  status=$$?; [ $$status = 0 ] || tail -n 20 "$$log" >&2; rm -f "$$log"; return $$status; }

# What building the compiled step core needs: a C compiler and $(PYTHON)'s headers.
HAVE_CC = command -v gcc >/dev/null && $(PYTHON) -c 'import os, sysconfig; \
  raise SystemExit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'

$(VENV)/.installed: pyproject.toml setup.py
	@$(APT_QUIET); $(PYTHON) -c 'import ensurepip, venv' 2>/dev/null || { \
	  if [ "$$(id -u)" = 0 ]; then apt_quiet python3-venv "the venv needs it" python3-venv; \
	  else echo "python3-venv is missing: run 'sudo apt-get install python3-venv'" >&2; exit 1; fi; }
	@$(APT_QUIET); $(HAVE_CC) 2>/dev/null || { \
	  if [ "$$(id -u)" = 0 ]; then apt_quiet "gcc and python3-dev" \
	    "the compiled step core is built with them" gcc libc6-dev python3-dev; \
	  else echo "the compiled step core needs gcc and the Python headers: run" \
	    "'sudo apt-get install gcc python3-dev'" >&2; exit 1; fi; \
	  $(HAVE_CC) || { echo "gcc or Python.h of $(PYTHON) still missing: install gcc and" \
	    "the -dev package of that Python" >&2; exit 1; }; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	PYTHONWARNINGS='ignore:Editable installation:UserWarning' $(BIN)/pip install -q -e '.[dev]'
	touch $@ $(VENV)/.stepcore

# The compiled step core again, in place, after a change to its sources (-Wall -Wextra -Werror).
stepcore: $(VENV)/.stepcore

STEPCORE_SRC = $(wildcard motion/executors/csrc/*.c motion/executors/csrc/*.h)
$(VENV)/.stepcore: $(VENV)/.installed setup.py $(STEPCORE_SRC)
	$(BIN)/python setup.py -q build_ext --inplace
	touch $@

# The step core's tests on the compiled core built with -fsanitize=address,undefined (into
# build/asan; MOTORCTL_STEPCORE makes every process load that build, the sanitizers' runtime
# preloaded): any error the sanitizers find fails the run.
ASAN_FLAGS = -O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined \
  -fno-sanitize-recover=all -fno-wrapv
ASAN_TESTS = tests/motion/executors/test_step_core.py tests/motion/executors/test_compiled_core.py \
  tests/motion/executors/process/
test-asan: venv
	rm -rf build/asan
	CFLAGS="$(ASAN_FLAGS)" LDFLAGS="-fsanitize=address,undefined" \
	  $(BIN)/python setup.py -q build_ext --build-lib build/asan/lib --build-temp build/asan/tmp
	cp build/asan/lib/motorctl/motion/executors/_stepcore*.so build/asan/_stepcore.so
	MOTORCTL_STEPCORE=$(CURDIR)/build/asan/_stepcore.so LD_PRELOAD="$$(gcc -print-file-name=libasan.so)" \
	  ASAN_OPTIONS=detect_leaks=0:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  PYTHONMALLOC=malloc sh -c '$(BIN)/python -c "from motorctl.motion.executors import compiled_core as c; \
	    assert c.load().__file__ == \"$$MOTORCTL_STEPCORE\""; \
	    $(BIN)/pytest -q -n $(JOBS) -p no:cacheprovider -k "compiled or both_cores" $(ASAN_TESTS)'

# The compiled code of the dataclasses' methods (motorctl/dataclass_code.py), in place, again
# after a change to any module of the package (setup.py's build_py writes it for the editable
# install, the wheel and the Debian package).
rwildcard = $(foreach d,$(wildcard $(1:=/*)),$(call rwildcard,$d,$2) $(filter $(subst *,%,$2),$d))
PACKAGE_SRC = $(call rwildcard,protocol client daemon motion hal,*.py) $(wildcard motorctl/*.py motorctl/schema/*.py)
dataclass-code: $(VENV)/.dataclass_code
$(VENV)/.dataclass_code: $(VENV)/.installed $(PACKAGE_SRC)
	$(BIN)/python -m motorctl.dataclass_code --write motorctl
	touch $@

run: venv stepcore dataclass-code
	$(BIN)/motorctld --pty $(PTY) --state-dir $(STATE) $(ARGS)

# What the tests need from Debian besides the venv: socat (tests/daemon/link/test_serialport_e2e.py);
# tshark and mergecap (tests/client/test_trace_files.py: the Lua dissector, merged files), with
# wireshark-common's debconf question answered (no setuid dumpcap: the tests only read files);
# dtc (tests/docs/test_wiring.py compiles docs/examples/motorctl-spi0-3cs-overlay.dts).
# As root, each missing one is installed quietly (apt_quiet above). Nothing else: the metrics'
# promtool lint runs on prometheus_client's parser (tests/support/promlint.py), promtool itself
# where it is installed already and in make test-deb; Debian's prometheus server package is
# never installed for it (tests/packaging/test_makefile.py holds this recipe to that).
# need_tool CMD PACKAGE WHY SKIPPED [DEBCONF]: as root, PACKAGE installed quietly (DEBCONF, a
# debconf answer, given first); else, or when that fails, one line on stderr saying what is
# SKIPPED and (not root) the command that installs it.
NEED_TOOL = $(APT_QUIET); need_tool() { \
  if [ "$$(id -u)" = 0 ]; then \
    { [ -z "$${5:-}" ] || echo "$$5" | debconf-set-selections; } \
    && apt_quiet "$$1" "$$3" "$$2" || echo "$$1 could not be installed: $$4" >&2; \
  else echo "$$1 is missing: run 'sudo apt-get install $$2'; until then $$4" >&2; fi; }

test-deps:
	@$(NEED_TOOL); command -v socat >/dev/null || need_tool socat socat \
	  "the serial device reconnect tests need it" "the serial device reconnect tests are SKIPPED"
	@$(NEED_TOOL); command -v tshark >/dev/null && command -v mergecap >/dev/null \
	  || need_tool tshark tshark "the Wireshark dissector's tests need it" \
	  "the Wireshark dissector's tests are SKIPPED" \
	  'wireshark-common wireshark-common/install-setuid boolean false'
	@$(NEED_TOOL); command -v dtc >/dev/null || need_tool dtc device-tree-compiler \
	  "the SPI0 overlay's test compiles it" "the SPI0 overlay's test is SKIPPED"

test: venv stepcore dataclass-code test-deps
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/pytest -q -n $(TEST_JOBS)

# The tests marked slow (pyproject.toml's addopts leaves them out of make test, to keep it near
# 90 s on 2 cores): the wheel built and installed beside python-daemon from PyPI
# (tests/packaging/test_wheel.py), hwtest/run's stand-in guests that run pytest on the
# checkout (tests/packaging/test_hwtest_run.py), the longer halves of two long runs (the status
# monitor's signal moments, tests/daemon/status/test_monitor_e2e.py; the rings between two
# processes, tests/motion/executors/process/test_rings.py). .ci/run runs them, a part of its own.
test-slow: venv stepcore dataclass-code test-deps
	$(BIN)/pytest -q -n $(JOBS) -m slow

# The conformance suite on dSPIN chips: the end-to-end tests of the protocol (every command and
# error code, held frames, hard stops, persistence, the service, the status document, the
# client, replay and trace) against motorctld serving docs/examples/dspin.toml's chain of mock
# chips: the test modules marked conformance. MOTORCTL_WORLD=dspin makes each test daemon's
# config that world's (tests/support/daemon_proc.py) and leaves out the tests about the STEP/DIR
# step executor itself (marked stepdir). Its own part of .ci/run: in make test it would make
# that half as long again.
test-dspin: venv stepcore dataclass-code test-deps
	MOTORCTL_WORLD=dspin $(BIN)/pytest -q -n $(JOBS) -m conformance

test-hw: stepcore dataclass-code
	hwtest/run all

# Unit coverage of the daemon's modules (the link, its session, state, service, status).
coverage: venv test-deps
	$(BIN)/pytest -q -n $(JOBS) --cov=motorctl.daemon --cov=motorctl.protocol.framing \
	  --cov-report=term-missing

# The robustness harness (docs/robustness.md): 10^6 frames, kill -9 cycles, reconnects during a
# WaitMoved, HAL faults, soak.
# ARGS="--quick" for a short run; the full run takes about 20 minutes.
robustness: venv
	$(BIN)/python -m bench.robustness $(ARGS)

bench: venv
	$(BIN)/python bench/latency.py
	$(BIN)/python bench/steps.py
	$(BIN)/python bench/noisy.py
	$(BIN)/python bench/rings.py
	$(BIN)/python bench/reconnect.py
	$(BIN)/python bench/instances.py
	$(BIN)/python bench/startup.py
	$(BIN)/python bench/replay.py

# The Debian package (dh + pybuild), built from the files git knows of (committed or not, not
# ignored), in build/deb/SUITE-ARCH: an orig tarball from git, debian/ beside it, patches
# applied there (never in the work tree). Built as Debian's build daemons do
# (tools/build-deb.sh): in a fresh root of SUITE (bookworm = Debian 12, the default; trixie =
# Debian 13) on ARCH (this machine's by default; arm64 on an amd64 machine runs under
# qemu-user through binfmt_misc) holding build-essential and debian/control's Build-Depends
# only (a debootstrap cached in build/, see tools/debroot.sh), as an unprivileged user,
# without network; so a Build-Depends missing from debian/control fails for everyone,
# whatever this machine has installed. Then lintian. Needs root. Result:
# build/deb/SUITE-ARCH/motorctl_<version>-1_ARCH.deb (log: build.log beside it). One package
# per release and architecture: it holds the compiled step core, built for that release's
# one Python (3.11 on Debian 12, 3.13 on Debian 13; docs/service.md says more).
# DEB_DEPS: what the host needs for make deb and make test-deb (not for building the package).
SUITE ?= bookworm
HOST_ARCH := $(shell dpkg --print-architecture 2>/dev/null || echo amd64)
ARCH ?= $(HOST_ARCH)
DEB_DEPS = debootstrap lintian systemd-container $(if $(filter-out $(HOST_ARCH),$(ARCH)),qemu-user-static binfmt-support)
DEB_VERSION = $(shell awk 'NR == 1 { v = $$2; gsub(/[()]/, "", v); sub(/-[^-]*$$/, "", v); print v }' debian/changelog)
DEB_DIR = build/deb/$(SUITE)-$(ARCH)
DEB_FILE = $(DEB_DIR)/motorctl_$(DEB_VERSION)-1_$(ARCH).deb
SYSPATH = /usr/sbin:/usr/bin:/sbin:/bin  # Debian's tools, not a venv's or pyenv's
DEBROOT = DEBROOT_SUITE=$(SUITE) DEBROOT_ARCH=$(ARCH)

deb-deps:
	@missing=$$(for p in $(DEB_DEPS); do dpkg-query -W -f='$${db:Status-Status}' $$p 2>/dev/null \
	  | grep -qx installed || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" != 0 ]; then echo "missing: sudo apt-get install $$missing" >&2; exit 1; fi; \
	  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q \
	    -o DPkg::Lock::Timeout=300 --no-install-recommends $$missing; \
	fi

deb: deb-deps
	rm -rf $(DEB_DIR) && mkdir -p $(DEB_DIR)
	git ls-files -z --cached --others --exclude-standard -- . ':!debian' ':!.ci' \
	  | tar --null -T - --sort=name --owner=0 --group=0 --mtime=@$$(git log -1 --format=%ct) \
	    --transform='s,^,motorctl-$(DEB_VERSION)/,S' -cf - \
	  | gzip -n > $(DEB_DIR)/motorctl_$(DEB_VERSION).orig.tar.gz
	tar -C $(DEB_DIR) -xzf $(DEB_DIR)/motorctl_$(DEB_VERSION).orig.tar.gz
	cp -a debian $(DEB_DIR)/motorctl-$(DEB_VERSION)/
	PATH=$(SYSPATH) $(DEBROOT) bash tools/build-deb.sh $(DEB_DIR)/motorctl-$(DEB_VERSION)
	PATH=$(SYSPATH) lintian --fail-on error --display-info $(DEB_FILE)
	@ls -l $(DEB_DIR)/*.deb

# Install the package on a fresh root of SUITE on ARCH (the same cached debootstrap) and check
# it there: see tests/deb/check-install.sh.
test-deb: deb
	PATH=$(SYSPATH) $(DEBROOT) bash tests/deb/check-install.sh $(DEB_FILE)

# The test suite in a fresh root of SUITE on ARCH with Debian's python3 and packages only (no
# venv, nothing from PyPI): all of it where ARCH runs natively, the part that proves what
# differs on an emulated ARCH otherwise (tests/deb/suite-in-root.sh says which and why;
# TESTS="..." chooses). E.g. make test-root SUITE=trixie ARCH=arm64: arm64 Python 3.13.
# It builds the compiled step core for the root's Python first and says which core the suite
# runs; it fails, before the tests, when the compiled one would not run.
test-root: deb-deps
	PATH=$(SYSPATH) $(DEBROOT) bash tests/deb/suite-in-root.sh $(TESTS)

clean:
	rm -rf build $(VENV) .run .pytest_cache .hypothesis .mypy_cache .ruff_cache *.egg-info \
	  motion/executors/_stepcore*.so
