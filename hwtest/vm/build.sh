#!/bin/bash
# build.sh [CACHE_DIR] - prepare a QEMU test VM with a real kernel GPIO subsystem (gpio-sim) for run.sh.
#   CACHE_DIR default: $GSIM_CACHE or ${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm
# Needs: Debian 12 (bookworm) amd64, root (apt-get install, debootstrap), Debian apt + PyPI access.
# The kernel packages: image, headers, headers-common, kbuild and source of one kernel, chosen from what the
#   archive holds now by kernel_tuple.py (its top says how; printed; recorded in KERNEL as the very last step,
#   and removed first: a build that does not finish leaves no KERNEL, and hwtest/run takes no VM without it).
#   Nothing fits: one line naming what is missing, exit 1, before anything is installed, downloaded or built.
# Env knobs: GSIM_KVER=6.1.0-56-amd64 (this ABI or none; default: what linux-image-amd64 depends on, else the
#   newest older ABI of its series whose five packages are all in the archive), GSIM_ROOTFS=0 (skip the
#   debootstrap bookworm rootfs = libgpiod v1, python3-spidev), GSIM_TRIXIE=0 (skip the debootstrap trixie root = Debian's
#   python3-libgpiod 2.x, the v2 API, python3-spidev, and gcc + python3-dev for the step core), GSIM_VENV=0 (skip the venv = PyPI gpiod v2 + spidev),
#   GSIM_PIP="gpiod spidev" (pin e.g. "gpiod==2.5.0 spidev==3.8"), GSIM_KEEP=1 (keep debs + extracted trees),
#   GSIM_PYTHON=/usr/bin/python3 (venv base), GSIM_MIRROR (debootstrap), GSIM_APT_UPDATE=0 (skip apt-get update).
# Result (~450 MB; ~70 MB without the roots): vmlinuz + vmlinux, initrd.img, mod/, rootfs/, trixie/, venv/,
#   VERSIONS, KERNEL (the five packages, name=version, one a line: kernel_tuple.py's output).
# Peak disk use while building ~1.2 GB. Re-running rebuilds kernel/modules/initramfs, keeps rootfs/ and venv/.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
C=${1:-${GSIM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm}}
MIRROR=${GSIM_MIRROR:-http://deb.debian.org/debian}
T0=$(date +%s); step() { echo "== [$(( $(date +%s) - T0 ))s] $*"; }
mkdir -p "$C"; C=$(cd "$C" && pwd); X=$C/x

step "choose the kernel packages (kernel_tuple.py)"
[ "$(id -u)" = 0 ] && [ "${GSIM_APT_UPDATE:-1}" = 1 ] && apt-get update -qq   # fresh lists -> current kernel ABI
[ -x /usr/bin/python3 ] || apt-get install -y --no-install-recommends python3-minimal
TUPLE=$(/usr/bin/python3 -I "$HERE/kernel_tuple.py" ${GSIM_KVER:+--kver "$GSIM_KVER"}) || {
  echo "build.sh: no VM built: no complete kernel tuple in the archive (the line above names what is missing)" >&2; exit 1; }
mapfile -t K <<< "$TUPLE"          # image, headers, headers-common, kbuild, source: name=version
[ ${#K[@]} = 5 ] || { echo "build.sh: kernel_tuple.py printed ${#K[@]} packages, not 5" >&2; exit 1; }
printf '  %s\n' "${K[@]}"
KVER=${K[0]%%=*}; KVER=${KVER#linux-image-}; ABI=${KVER%-amd64}   # 6.1.0-56-amd64 -> 6.1.0-56
S=${K[4]%%=*}                                                     # linux-source-6.1

step "host packages"
P="qemu-system-x86 cpio kmod xz-utils gcc make libc6-dev"
{ [ "${GSIM_ROOTFS:-1}" = 1 ] || [ "${GSIM_TRIXIE:-1}" = 1 ]; } && P="$P debootstrap"
[ "${GSIM_VENV:-1}" = 1 ] && P="$P python3-venv python3-dev"   # spidev on PyPI is an sdist: needs gcc + Python.h
miss=; for p in $P; do dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'ok installed' || miss="$miss $p"; done
[ -z "$miss" ] || apt-get install -y --no-install-recommends $miss
rm -f "$C/KERNEL"; rm -rf "$X"; mkdir -p "$X" "$C/debs"           # from here on the cache is changed

step "download kernel image/headers/kbuild/source"
cd "$C/debs"
apt-get -o APT::Sandbox::User=root download "${K[@]}" busybox-static
deb() {  # deb NAME=VERSION: the file apt-get download made of it (an epoch's colon is %3a)
  local v=${1#*=}; local f=("$C/debs/${1%%=*}_${v/:/%3a}"_*.deb)
  [ -f "${f[0]}" ] || { echo "build.sh: no download of $1 in $C/debs" >&2; exit 1; }
  echo "${f[0]}"
}

step "extract"
dpkg-deb -x "$(deb "${K[0]}")" "$X/img"
cp "$X/img/boot/vmlinuz-$KVER" "$C/vmlinuz"
# also unpack the xz payload of the bzImage (a stripped ELF vmlinux with a PVH entry note): QEMU boots it
# directly (PVH), which skips ~2.5 s of in-guest decompression under TCG. xz complains about trailing data.
off=$(LC_ALL=C grep -obUaP '\xfd7zXZ\x00' "$C/vmlinuz" | head -1 | cut -d: -f1)
tail -c +$((${off:-0} + 1)) "$C/vmlinuz" | xz -dcq > "$C/vmlinux" 2>/dev/null || true
readelf -n "$C/vmlinux" 2>/dev/null | grep -q 'note type: (0x00000012)' || rm -f "$C/vmlinux"  # no PVH note -> use bzImage
for p in "${K[1]}" "${K[2]}" "${K[3]}"; do dpkg-deb -x "$(deb "$p")" "$X/hdr"; done
KB=$X/hdr/usr/src/linux-headers-$KVER
sed -i "s|^include /usr/src/|include $X/hdr/usr/src/|" "$KB/Makefile"   # point at the extracted -common tree
dpkg-deb -x busybox-static_*.deb "$X/bb"
dpkg-deb --fsys-tarfile "$(deb "${K[4]}")" | tar -xO "./usr/src/$S.tar.xz" | tar -xJ -C "$X" \
  $S/drivers/gpio/gpio-sim.c $S/drivers/gpio/gpiolib.h $S/kernel/irq/irq_sim.c $S/drivers/spi/spi-gpio.c $S/drivers/spi/spi-bitbang-txrx.h

step "build out-of-tree modules: irq-sim gpio-sim spi-gpio spi-sim"
rm -rf "$C/mod"; mkdir -p "$C/mod"; cd "$C/mod"
cp "$X/$S"/drivers/gpio/{gpio-sim.c,gpiolib.h} "$X/$S"/kernel/irq/irq_sim.c "$X/$S"/drivers/spi/{spi-gpio.c,spi-bitbang-txrx.h} "$HERE/spi-sim.c" .
sed -i 's/handle_simple_irq(irq_to_desc(irqnum));/generic_handle_irq(irqnum);/' irq_sim.c  # irq_to_desc is not exported
printf '#include <linux/module.h>\n#include "irq_sim.c"\nMODULE_LICENSE("GPL");\n' > irq-sim.c
echo 'obj-m += irq-sim.o gpio-sim.o spi-gpio.o spi-sim.o' > Makefile
make -s -C "$KB" M="$C/mod" modules

step "initramfs"
I=$X/initramfs; mkdir -p "$I"/{bin,dev,proc,sys,run,lib/modules}
cp "$X/bb/bin/busybox" "$I/bin/"; cp "$HERE/init.sh" "$I/init"; chmod 755 "$I/init"
depmod -b "$X/img" "$KVER"
deps() { for m; do modprobe -d "$X/img" -S "$KVER" --show-depends "$m"; done | awk '$1=="insmod"{print $2}' | awk '!s[$0]++'; }
for f in $(deps 9pnet_virtio virtio_pci 9p overlay configfs) $(deps spi-bitbang); do cp "$f" "$I/lib/modules/"; done
{ deps 9pnet_virtio virtio_pci 9p overlay configfs | xargs -n1 basename; echo irq-sim.ko; echo gpio-sim.ko; } > "$I/lib/modules/base.list"
{ deps spi-bitbang | xargs -n1 basename; echo spi-gpio.ko; echo spi-sim.ko; } > "$I/lib/modules/spi.list"
cp "$C/mod"/*.ko "$I/lib/modules/"
(cd "$I" && find . | cpio -o -H newc --quiet | gzip -1) > "$C/initrd.img"

if [ "${GSIM_ROOTFS:-1}" = 1 ] && [ ! -x "$C/rootfs/usr/bin/python3" ]; then
  step "debootstrap bookworm rootfs with python3-libgpiod (libgpiod v1 API) and python3-spidev"
  rm -rf "$C/rootfs"
  debootstrap --variant=minbase --include=python3-minimal,python3-libgpiod,gpiod,python3-serial,python3-pytest,python3-spidev bookworm "$C/rootfs" "$MIRROR" > "$X/debootstrap.log"
  rm -f "$C/rootfs"/var/cache/apt/archives/*.deb
fi
if [ "${GSIM_TRIXIE:-1}" = 1 ] && [ ! -x "$C/trixie/usr/bin/python3" ]; then
  step "debootstrap trixie rootfs with Debian's python3-libgpiod 2 (libgpiod v2 API) and python3-spidev"
  rm -rf "$C/trixie"
  # gcc, python3-dev, python3-setuptools: the guest builds the compiled step core for Python 3.13 (hwtest/run)
  debootstrap --variant=minbase --include=python3-minimal,python3-libgpiod,gpiod,python3-serial,python3-pytest,python3-spidev,gcc,libc6-dev,python3-dev,python3-setuptools trixie "$C/trixie" "$MIRROR" > "$X/debootstrap-trixie.log"
  rm -f "$C/trixie"/var/cache/apt/archives/*.deb
fi
if [ "${GSIM_VENV:-1}" = 1 ] && [ ! -x "$C/venv/bin/python" ]; then
  step "venv with PyPI gpiod (libgpiod v2 API) + spidev, for the host-root guest"
  "${GSIM_PYTHON:-/usr/bin/python3}" -m venv "$C/venv"
  "$C/venv/bin/pip" install -q --disable-pip-version-check ${GSIM_PIP:-gpiod==2.5.0 spidev==3.8 pyserial==3.5 pytest==8.3.5}
fi

step "record versions"
{ echo "kernel: ${K[*]}"
  echo "busybox-static: $(dpkg-deb -f "$C"/debs/busybox-static_*.deb Version)"
  echo "qemu: $(qemu-system-x86_64 --version | head -1)"
  [ -d "$C/rootfs" ] && echo "rootfs: bookworm, $(dpkg-query --admindir="$C/rootfs/var/lib/dpkg" -W -f='${Package} ${Version}, ' python3-libgpiod python3.11 gpiod python3-spidev)"
  [ -d "$C/trixie" ] && echo "trixie: $(dpkg-query --admindir="$C/trixie/var/lib/dpkg" -W -f='${Package} ${Version}, ' python3-libgpiod python3.13 gpiod python3-spidev)"
  [ -d "$C/venv" ] && echo "venv: $("$C/venv/bin/python" --version), $("$C/venv/bin/pip" list --format=freeze 2>/dev/null | grep -Ei '^(gpiod|spidev)=' | tr '\n' ' ')"
} | tee "$C/VERSIONS"
[ "${GSIM_KEEP:-0}" = 1 ] || rm -rf "$X" "$C/debs"
printf '%s\n' "${K[@]}" > "$C/KERNEL.new" && mv "$C/KERNEL.new" "$C/KERNEL"   # last: the VM is whole
step "done: $(du -sh "$C" | cut -f1) in $C"
