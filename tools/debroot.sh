# Sourced by tools/build-deb.sh (make deb) and tests/deb/check-install.sh (make test-deb):
# fresh Debian 12 roots, each unpacked anew from one cached debootstrap.
#
# The base is `debootstrap --variant=minbase bookworm`, made once and cached as
# build/bookworm-minbase.tar (about 30 s to make, 200 MB); it is made again when it is older
# than $DEBROOT_MAX_AGE_DAYS (7) so its packages stay near the archive's. Every user of a root
# unpacks a fresh copy of it, so nothing one run installed is seen by the next: the package
# build gets exactly the Build-Depends (plus build-essential), the install check exactly the
# package's Depends. Needs root (debootstrap, chroot, mounts), debootstrap and the Debian
# archive ($DEBIAN_MIRROR); each says so when missing.

debroot_here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
debroot_build=$debroot_here/build
debroot_base=$debroot_build/bookworm-minbase.tar
debroot_mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}

debroot_fail() { echo "FAILED: $*" >&2; exit 1; }

# debroot_needs WHAT: root and the host commands a root needs, or a message naming the fix.
debroot_needs() {
  if [ "$(id -u)" != 0 ]; then
    echo "$1 needs root (debootstrap, chroot and mounts for a fresh Debian 12 root): run it with sudo" >&2
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
}

# debroot_base_tar: make the cached base when it is missing or older than the limit.
debroot_base_tar() {
  mkdir -p "$debroot_build"
  if [ -f "$debroot_base" ] && [ -z "$(find "$debroot_base" -mtime +"${DEBROOT_MAX_AGE_DAYS:-7}")" ]; then
    return 0
  fi
  local t0=$SECONDS tmp=$debroot_build/debootstrap
  echo "== debootstrap bookworm (minbase) into $debroot_base (cached for ${DEBROOT_MAX_AGE_DAYS:-7} days)"
  rm -rf "$tmp"
  debootstrap --variant=minbase bookworm "$tmp" "$debroot_mirror" >"$debroot_build/debootstrap.log" 2>&1 \
    || { tail -20 "$debroot_build/debootstrap.log"; rm -rf "$tmp"
         debroot_fail "debootstrap (log: $debroot_build/debootstrap.log; mirror $debroot_mirror)"; }
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
  chroot "$root" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 \
    DEBIAN_FRONTEND=noninteractive "$@"
}
