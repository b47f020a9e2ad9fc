#!/usr/bin/env bash
# The project's test suite in a fresh Debian root, with Debian's python3 and Debian's packages
# only: no venv, nothing from PyPI (make test-root SUITE=... ARCH=...).
#   tests/deb/suite-in-root.sh [PYTEST ARGS...]   (default: the selection below)
# The root is a fresh copy of the cached debootstrap of DEBROOT_SUITE on DEBROOT_ARCH
# (tools/debroot.sh; arm64 on this amd64 machine runs under qemu-user) plus the packages the
# suite imports (PACKAGES), and a copy of the files git knows of in /src (the work tree is
# never written). It says which step core the suite runs (the compiled one, built in the root
# for its Python; the run fails when that one would not run). Log:
# build/deb/suite-SUITE-ARCH/pytest.log.
#
# Which tests (docs/platforms.md has the figures):
# - where ARCH runs natively: all of them (`make test`'s selection).
# - under emulation: the part that proves what differs on another architecture, since the
#   whole suite takes about 26 minutes there (measured on this 2-core machine, trixie arm64,
#   pytest -n 2, load 7-9) against about 2.5 natively:
#     tests/motion/executors/test_step_core.py        the compiled step core (built here, for
#                                                     arm64's Python 3.13) against the Python
#                                                     reference, on a virtual clock
#     tests/motion/executors/process/test_rings.py    the shared-memory rings' ordering between
#                                                     two processes (arm64's weaker memory order)
#     tests/motion/executors/process/test_parent.py,  the step executor as a process of its own
#       tests/motion/executors/process/test_child.py  (the daemon's side and the child's)
#     tests/daemon/start/test_serve_e2e.py                  motorctld end to end on a PTY
#     tests/packaging/test_debian.py                  the package build's runs under Debian's
#                                                     python3
#     tests/protocol tests/contract                   the frames (byte order, struct) and the
#                                                     mock backend's contract, cheap
#   and, inside those, not the tests that judge step lateness with the real motors' rule
#   (marker real_rule, and [mock] lose_steps = true): an emulated CPU makes every step late,
#   so they measure the emulator (the make test and bench/ runs judge timing).
#   The arm64 package itself (installed, started by its unit, answering) is make test-deb
#   SUITE=trixie ARCH=arm64.
# Left out everywhere here (they need what this root deliberately lacks, and run in make test):
#   tests/docs/test_readme.py (the README's walkthrough uses the checkout's .venv),
#   tests/packaging/test_wheel.py and test_version.py (pip and an installed wheel's metadata).
set -euo pipefail
here=$(cd "$(dirname "$0")/../.." && pwd)
# shellcheck source=tools/debroot.sh
. "$here/tools/debroot.sh"
debroot_needs "make test-root"
# the suite's imports (radon: tests/test_layout.py's complexity; Debian's package of it is
# named radon), socat (tests it runs), and what building the compiled step core for
# the root's Python needs (gcc, its headers, setuptools: as debian/control's Build-Depends)
PACKAGES="python3-pytest python3-pytest-xdist python3-hypothesis python3-serial python3-libgpiod
  python3-spidev python3-systemd python3-prometheus-client python3-rich radon socat
  gcc libc6-dev python3-dev python3-setuptools"
EMULATED=(tests/motion/executors/test_step_core.py tests/motion/executors/process/test_rings.py
  tests/motion/executors/process/test_parent.py tests/motion/executors/process/test_child.py
  tests/daemon/start/test_serve_e2e.py tests/packaging/test_debian.py tests/protocol tests/contract
  -m "not slow and not real_rule" -k "not lose_steps")
NEEDS_THE_CHECKOUT=(--ignore=tests/docs/test_readme.py --ignore=tests/packaging/test_wheel.py
  --ignore=tests/packaging/test_version.py)
# Under emulation a re-plan can reach the step executor milliseconds late (a soft stop or a
# reversal in test_serve_e2e then faulted with "re-plan came 2476 us late", once, at load
# 7-9): the test daemons there cut a running plan 25 ms after the command instead of 3
# ([step_thread] lead_ms, docs/timing.md), as a user of so loaded a board would.
lead=""
[ -n "$debroot_qemu" ] && lead="lead_ms=25"
if [ $# -gt 0 ]; then
  selection=("$@")
elif [ -n "$debroot_qemu" ]; then
  selection=("${EMULATED[@]}")
else
  selection=(tests -m "not slow" "${NEEDS_THE_CHECKOUT[@]}")
fi
out=$debroot_build/deb/suite-$debroot_tag
mkdir -p "$out"
root=$debroot_build/suite-root-$debroot_tag
trap 'debroot_remove "$root"' EXIT
debroot_fresh "$root"

t0=$SECONDS
echo "== a fresh $debroot_release $debroot_arch root with Debian's packages for the suite"
# shellcheck disable=SC2086  # a list of package names
{ debroot_run "$root" apt-get update -q \
  && debroot_run "$root" apt-get install -y -q --no-install-recommends $PACKAGES
} > "$out/apt.log" 2>&1 || { tail -20 "$out/apt.log"; debroot_fail "installing the suite's packages (log: $out/apt.log)"; }
echo "   installed in $((SECONDS - t0)) s: $(debroot_run "$root" python3 --version)," \
  "$(debroot_run "$root" dpkg-query -W -f='${Package} ${Version}, ' python3-pytest python3-libgpiod)"
mkdir -p "$root/src"
git -C "$here" ls-files -z --cached --others --exclude-standard -- . ':!build' \
  | tar -C "$here" --null -T - -cf - | tar -C "$root/src" -xf -

t1=$SECONDS
echo "== the compiled step core for the root's $(debroot_run "$root" python3 --version), built in /src"
debroot_run "$root" sh -c "cd /src && python3 setup.py -q build_ext --inplace --build-temp /tmp/stepcore" \
  > "$out/stepcore.log" 2>&1 || { tail -20 "$out/stepcore.log"; debroot_fail "building the compiled step core (log: $out/stepcore.log)"; }
echo "   built in $((SECONDS - t1)) s: $(cd "$root/src/motion/executors" && ls _stepcore*.so)"
# and the dataclasses' compiled methods for the root's Python, as make and the package's build
# write them (motorctl/dataclass_code.py): a start without them warns that they are absent
t1=$SECONDS
debroot_run "$root" sh -c "cd /src && PYTHONDONTWRITEBYTECODE=1 python3 -m motorctl.dataclass_code --write motorctl" \
  > "$out/dataclass-code.log" 2>&1 || { tail -20 "$out/dataclass-code.log"; debroot_fail "writing the dataclasses' compiled methods (log: $out/dataclass-code.log)"; }
echo "   the dataclasses' compiled methods in $((SECONDS - t1)) s: $(tail -1 "$out/dataclass-code.log")"
# The step core the suite runs, as the daemon chooses it (--probe, [step_thread] core =
# "auto"): the compiled one, built above. Any other answer fails the run here, before the
# tests: a suite on the Python core would pass with the compiled core untested (as it once
# did on bookworm, whose setuptools could not read pyproject.toml's licence).
debroot_run "$root" sh -c "cd /src && python3 -m motorctl.daemon.start.main --probe --latency-seconds 0" \
  > "$out/probe.txt" 2>&1 || { cat "$out/probe.txt"; debroot_fail "motorctld --probe in the root (log: $out/probe.txt)"; }
runs=$(sed -n 's/^  runs: //p' "$out/probe.txt")
echo "== the step core the suite runs: ${runs:-none} (motorctld --probe in the root)"
[ "$runs" = compiled ] || { sed -n '/^step core:/,/^  runs:/p' "$out/probe.txt"
  debroot_fail "the compiled step core was built for the root's python3 but would not run: the suite is NOT run on the Python core in its place"; }

t1=$SECONDS
args=""; for a in "${selection[@]}"; do args="$args '${a//\'/\'\\\'\'}'"; done
echo "== pytest -n ${JOBS:-2} in /src${lead:+ (test daemons: [step_thread] $lead)}:${args}"
status=0
debroot_run "$root" HOME=/root MOTORCTL_TEST_STEP_THREAD="$lead" sh -c "cd /src && python3 -m pytest -q -n ${JOBS:-2} \
  -p no:cacheprovider -o addopts=-ra --durations=10 $args" 2>&1 | tee "$out/pytest.log" \
  || status=$?
echo "== the suite on $debroot_release $debroot_arch: $([ $status = 0 ] && echo passed || echo "FAILED ($status)") in $((SECONDS - t1)) s (log: $out/pytest.log)"
exit $status
