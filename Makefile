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

.PHONY: run test test-hw lint bench coverage robustness clean venv deb deb-deps test-deb

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
	$(BIN)/python bench/rings.py
	$(BIN)/python bench/startup.py

# The Debian package (dh + pybuild), built from the files git knows of (committed or not, not
# ignored), in build/deb: an orig tarball from git, debian/ beside it, patches applied
# there (never in the work tree). Result: build/deb/motorctl_<version>-1_all.deb.
DEB_DEPS = build-essential debhelper dh-python pybuild-plugin-pyproject python3-all \
           python3-setuptools python3-build python3-installer python3-wheel lintian \
           debootstrap fakeroot systemd-container help2man
DEB_VERSION = $(shell awk 'NR == 1 { v = $$2; gsub(/[()]/, "", v); sub(/-[^-]*$$/, "", v); print v }' debian/changelog)
DEB_DIR = build/deb
SYSPATH = /usr/sbin:/usr/bin:/sbin:/bin  # Debian's python3, not a venv's or pyenv's

deb-deps:
	@missing=$$(for p in $(DEB_DEPS); do dpkg-query -W -f='$${db:Status-Status}' $$p 2>/dev/null \
	  | grep -qx installed || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" != 0 ]; then echo "missing: sudo apt-get install $$missing" >&2; exit 1; fi; \
	  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $$missing; \
	fi

deb: deb-deps
	rm -rf $(DEB_DIR) && mkdir -p $(DEB_DIR)
	git ls-files -z --cached --others --exclude-standard -- . ':!debian' ':!.ci' \
	  | tar --null -T - --sort=name --owner=0 --group=0 --mtime=@$$(git log -1 --format=%ct) \
	    --transform='s,^,motorctl-$(DEB_VERSION)/,S' -cf - \
	  | gzip -n > $(DEB_DIR)/motorctl_$(DEB_VERSION).orig.tar.gz
	tar -C $(DEB_DIR) -xzf $(DEB_DIR)/motorctl_$(DEB_VERSION).orig.tar.gz
	cp -a debian $(DEB_DIR)/motorctl-$(DEB_VERSION)/
	cd $(DEB_DIR)/motorctl-$(DEB_VERSION) && PATH=$(SYSPATH) dpkg-buildpackage -us -uc -b
	PATH=$(SYSPATH) lintian --fail-on error --display-info $(DEB_DIR)/motorctl_$(DEB_VERSION)-1_all.deb
	@ls -l $(DEB_DIR)/*.deb

# Install the package on a fresh Debian 12 root (debootstrap, cached in build/) and check
# it there: see tests/deb/check-install.sh.
test-deb: deb
	bash tests/deb/check-install.sh $(DEB_DIR)/motorctl_$(DEB_VERSION)-1_all.deb

clean:
	rm -rf build $(VENV) .run .pytest_cache .hypothesis .mypy_cache .ruff_cache *.egg-info
