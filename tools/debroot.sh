# Sourced by tools/build-deb.sh (make deb), tests/deb/check-install.sh (make test-deb) and
# tests/deb/suite-in-root.sh (make test-root): fresh Debian roots of one release and
# architecture, each unpacked anew from one cached debootstrap.
#
# Which root: DEBROOT_SUITE (bookworm or trixie; default bookworm) and DEBROOT_ARCH (a Debian
# architecture, default this machine's). The base is `debootstrap --variant=minbase
# --include=python3 SUITE`, made once and cached as build/SUITE-ARCH-base.tar (bookworm on
# amd64: about 40 s and 230 MB); it is made again when it is older than
# $DEBROOT_MAX_AGE_DAYS (7) so its packages stay near the archive's. Every user of a root
# unpacks a fresh copy of it, so nothing one step installed is seen by the next: the package
# build gets exactly the Build-Depends (plus build-essential), the install check exactly the
# package's Depends, the suite exactly its test packages. python3 is in the base because
# every one of those closures holds it (Build-Depends python3-all, Depends
# ${python3:Depends}, the suite): installed once, not once per root; under emulation,
# compiling its standard library is a minute of each.
#
# Another architecture (arm64 on an amd64 machine) runs through qemu-user (Debian's
# qemu-user-static, registered with binfmt_misc with the F flag, so it works in a chroot);
# debroot_needs mounts binfmt_misc where it is not. Every command in such a root gets
# QEMU_CPU=$DEBROOT_QEMU_CPU (arm64: cortex-a72, a Raspberry Pi 4's core): QEMU's default
# arm64 CPU emulates pointer authentication with the QARMA5 cipher, and Debian 13 builds its
# arm64 binaries with branch protection, so every function call ran that cipher: python3
# started about ten times slower (measured: 53 s against 4.5 s for the same script). On a
# Cortex-A72, which has no pointer authentication, those instructions are no-ops, as on a
# Pi 4. Needs root (debootstrap, chroot, mounts), debootstrap and the Debian archive
# ($DEBIAN_MIRROR); each says so when missing.

debroot_here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
debroot_build=$debroot_here/build
debroot_mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
debroot_suite=${DEBROOT_SUITE:-bookworm}
debroot_host_arch=$(dpkg --print-architecture 2>/dev/null || echo amd64)
debroot_arch=${DEBROOT_ARCH:-$debroot_host_arch}
debroot_tag=$debroot_suite-$debroot_arch
debroot_base=$debroot_build/$debroot_tag-base.tar
case $debroot_suite in
  bookworm) debroot_release="Debian 12 (bookworm)" ;;
  trixie) debroot_release="Debian 13 (trixie)" ;;
  *) echo "DEBROOT_SUITE must be bookworm or trixie, not '$debroot_suite'" >&2; exit 2 ;;
esac
# the qemu-user name of a foreign architecture; empty: this machine runs it natively
debroot_qemu=
if [ "$debroot_arch" != "$debroot_host_arch" ] \
  && ! { [ "$debroot_host_arch" = amd64 ] && [ "$debroot_arch" = i386 ]; }; then
  case $debroot_arch in
    arm64) debroot_qemu=aarch64 ;;
    armhf | armel) debroot_qemu=arm ;;
    riscv64 | s390x) debroot_qemu=$debroot_arch ;;
    ppc64el) debroot_qemu=ppc64le ;;
    *) echo "DEBROOT_ARCH '$debroot_arch': not a Debian architecture this knows" >&2; exit 2 ;;
  esac
fi
debroot_qemu_cpu=
[ "$debroot_arch" = arm64 ] && [ -n "$debroot_qemu" ] && debroot_qemu_cpu=${DEBROOT_QEMU_CPU:-cortex-a72}
# the environment every command in a root starts with
debroot_env=(PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8)
[ -n "$debroot_qemu_cpu" ] && debroot_env+=("QEMU_CPU=$debroot_qemu_cpu")

debroot_fail() { echo "FAILED: $*" >&2; exit 1; }

# debroot_needs WHAT: root, the host commands a root needs, and for another architecture
# qemu-user through binfmt_misc; or a message naming the fix.
debroot_needs() {
  if [ "$(id -u)" != 0 ]; then
    echo "$1 needs root (debootstrap, chroot and mounts for a fresh $debroot_release root): run it with sudo" >&2
    exit 2
  fi
  local cmd missing=
  for cmd in debootstrap chroot mount unshare tar; do
    command -v "$cmd" >/dev/null 2>&1 || missing="$missing $cmd"
  done
  if [ -n "$missing" ]; then
    echo "$1 needs:$missing (make deb-deps installs them: apt-get install debootstrap)" >&2
    exit 2
  fi
  [ -n "$debroot_qemu" ] || return 0
  local misc=/proc/sys/fs/binfmt_misc entry
  if [ ! -e "$misc/status" ]; then
    mount -t binfmt_misc binfmt_misc "$misc" 2>/dev/null \
      || { echo "$1 for $debroot_arch: binfmt_misc is not mounted and mounting it failed (mount -t binfmt_misc binfmt_misc $misc)" >&2; exit 2; }
  fi
  entry=$misc/qemu-$debroot_qemu
  if [ ! -e "$entry" ] && command -v update-binfmts >/dev/null 2>&1; then
    update-binfmts --enable "qemu-$debroot_qemu" >/dev/null 2>&1 || true
  fi
  if ! grep -qx enabled "$entry" 2>/dev/null || ! grep -q '^flags: .*F' "$entry"; then
    echo "$1 for $debroot_arch runs its programs through qemu-user: apt-get install qemu-user-static binfmt-support (make deb-deps ARCH=$debroot_arch), then update-binfmts --enable qemu-$debroot_qemu ($entry is missing, disabled or lacks the F flag a chroot needs)" >&2
    exit 2
  fi
}

# debroot_base_tar: make the cached base when it is missing or older than the limit.
debroot_base_tar() {
  mkdir -p "$debroot_build"
  if [ -f "$debroot_base" ] && [ -z "$(find "$debroot_base" -mtime +"${DEBROOT_MAX_AGE_DAYS:-7}")" ]; then
    return 0
  fi
  local t0=$SECONDS tmp=$debroot_build/debootstrap-$debroot_tag log=$debroot_build/debootstrap-$debroot_tag.log
  echo "== debootstrap $debroot_suite $debroot_arch (minbase, python3) into $debroot_base (cached for ${DEBROOT_MAX_AGE_DAYS:-7} days)"
  rm -rf "$tmp"
  env ${debroot_qemu_cpu:+QEMU_CPU=$debroot_qemu_cpu} debootstrap --arch="$debroot_arch" \
    --variant=minbase --include=python3 "$debroot_suite" "$tmp" "$debroot_mirror" >"$log" 2>&1 \
    || { tail -20 "$log"; debroot_remove "$tmp"
         debroot_fail "debootstrap (log: $log; mirror $debroot_mirror)"; }
  debroot_umount "$tmp"
  tar -C "$tmp" -cf "$debroot_base.new" . && mv "$debroot_base.new" "$debroot_base"
  rm -rf "$tmp"
  echo "   made in $((SECONDS - t0)) s"
}

# debroot_mount ROOT / debroot_umount ROOT: what a chroot needs of /proc and /dev.
debroot_mount() {
  mount -t proc proc "$1/proc"
  mount --bind /dev "$1/dev"
  mount --bind /dev/pts "$1/dev/pts"
  mount -t tmpfs -o mode=1777 shm "$1/dev/shm"  # POSIX shared memory (the step executor's)
}
debroot_umount() {
  local m
  for m in dev/shm dev/pts dev proc; do
    if mountpoint -q "$1/$m"; then umount -l "$1/$m"; fi
  done
}

# debroot_fresh ROOT: a fresh copy of the base at ROOT (anything there before is removed),
# mounted, with the host's resolver; debroot_remove ROOT undoes it.
debroot_fresh() {
  debroot_base_tar
  debroot_remove "$1"
  mkdir -p "$1"
  tar -C "$1" -xf "$debroot_base"
  debroot_mount "$1"
  cp /etc/resolv.conf "$1/etc/resolv.conf" 2>/dev/null || true
}
debroot_remove() {
  [ -d "$1" ] || return 0
  debroot_umount "$1"
  rm -rf "$1"
}

# debroot_run ROOT COMMAND...: COMMAND as root in ROOT, with a clean environment.
debroot_run() {
  local root=$1; shift
  chroot "$root" env -i "${debroot_env[@]}" DEBIAN_FRONTEND=noninteractive "$@"
}
