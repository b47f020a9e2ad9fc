#!/usr/bin/env bash
# Build the Debian package the way Debian's build daemons do (make deb):
#   tools/build-deb.sh SRCDIR     SRCDIR = build/deb/SUITE-ARCH/motorctl-<version> (debian/
#                                 inside, the orig tarball beside it, as the Makefile lays
#                                 them out)
# in a fresh root of DEBROOT_SUITE on DEBROOT_ARCH (tools/debroot.sh: a cached debootstrap,
# unpacked anew; another architecture runs under qemu-user) that holds build-essential and
# the package's Build-Depends, nothing else: a module or tool the build uses and
# debian/control does not name fails the build here, whatever the host has installed. The
# build runs as an unprivileged user (Rules-Requires-Root: no) without network (unshare
# --net), as on a buildd; on arm64 it is a native arm64 build (gcc, python3-dev and the
# interpreter are arm64's), which an Architecture: any package with compiled code needs. The
# .deb, .buildinfo and .changes land beside SRCDIR; logs there too: build-deps.log (apt)
# and build.log (dpkg-buildpackage).
set -euo pipefail
src=$(realpath "${1:?usage: tools/build-deb.sh build/deb/motorctl-VERSION}")
out=$(dirname "$src")
name=$(basename "$src")
# shellcheck source=tools/debroot.sh
. "$(dirname "$0")/debroot.sh"
debroot_needs "make deb"
[ -f "$src/debian/control" ] || debroot_fail "$src/debian/control: no such file"

root=$debroot_build/deb-build-root-$debroot_tag
trap 'debroot_remove "$root"' EXIT
debroot_fresh "$root"
t0=$SECONDS
echo "== a fresh $debroot_release $debroot_arch root (Debian $(cat "$root/etc/debian_version")): build-essential and the Build-Depends only"
mkdir -p "$root/build"
cp -a "$src" "$root/build/"
cp -a "$out"/*.orig.tar.* "$root/build/"
log=$out/build-deps.log
{ debroot_run "$root" apt-get update -q \
  && debroot_run "$root" apt-get install -y -q --no-install-recommends build-essential \
  && debroot_run "$root" apt-get build-dep -y -q --no-install-recommends "/build/$name"
} >"$log" 2>&1 || { tail -20 "$log"; debroot_fail "installing the Build-Depends (log: $log)"; }
echo "   Build-Depends installed in $((SECONDS - t0)) s:" \
  "$(debroot_run "$root" dpkg-query -W -f='${Package}\n' | wc -l) packages in the root"

t1=$SECONDS
debroot_run "$root" useradd --system --user-group --create-home --home-dir /home/builder builder
debroot_run "$root" chown -R builder:builder /build
blog=$out/build.log
echo "== dpkg-buildpackage -b as an unprivileged user, without network (log: $blog)"
unshare --net chroot --userspec=builder:builder "$root" \
  env -i "${debroot_env[@]}" HOME=/home/builder \
  sh -c "cd /build/$name && dpkg-buildpackage -us -uc -b" >"$blog" 2>&1 \
  || { tail -30 "$blog"; debroot_fail "dpkg-buildpackage in the clean root (log: $blog)"; }
cp "$root/build/"*.deb "$root/build/"*.buildinfo "$root/build/"*.changes "$out/"
echo "   built in $((SECONDS - t1)) s: $(cd "$out" && ls ./*.deb)"
