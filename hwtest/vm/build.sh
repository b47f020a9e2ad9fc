#!/bin/bash
# build.sh [CACHE_DIR] - prepare a QEMU test VM with a real kernel GPIO subsystem (gpio-sim) for run.sh.
#   CACHE_DIR default: $GSIM_CACHE or ${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm
# Needs: Debian 12 (bookworm) amd64, root (apt-get install, debootstrap), Debian apt + PyPI access.
# Env knobs: GSIM_KVER=6.1.0-56-amd64 (default: what linux-image-amd64 depends on), GSIM_ROOTFS=0 (skip the
#   debootstrap bookworm rootfs = libgpiod v1), GSIM_TRIXIE=0 (skip the debootstrap trixie root = Debian's
#   python3-libgpiod 2.x, the v2 API, python3-spidev, and gcc + python3-dev for the step core), GSIM_VENV=0 (skip the venv = PyPI gpiod v2 + spidev),
#   GSIM_PIP="gpiod spidev" (pin e.g. "gpiod==2.5.0 spidev==3.8"), GSIM_KEEP=1 (keep debs + extracted trees),
#   GSIM_PYTHON=/usr/bin/python3 (venv base), GSIM_MIRROR (debootstrap), GSIM_APT_UPDATE=0 (skip apt-get update).
# Result (~450 MB; ~70 MB without the roots): vmlinuz + vmlinux, initrd.img, mod/, rootfs/, trixie/, venv/,
#   VERSIONS.
# Peak disk use while building ~1.2 GB. Re-running rebuilds kernel/modules/initramfs, keeps rootfs/ and venv/.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
C=${1:-${GSIM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm}}
MIRROR=${GSIM_MIRROR:-http://deb.debian.org/debian}
T0=$(date +%s); step() { echo "== [$(( $(date +%s) - T0 ))s] $*"; }
mkdir -p "$C"; C=$(cd "$C" && pwd); X=$C/x; rm -rf "$X"; mkdir -p "$X" "$C/debs"

step "host packages"
[ "$(id -u)" = 0 ] && [ "${GSIM_APT_UPDATE:-1}" = 1 ] && apt-get update -qq   # fresh lists -> current kernel ABI
P="qemu-system-x86 cpio kmod xz-utils gcc make libc6-dev"
{ [ "${GSIM_ROOTFS:-1}" = 1 ] || [ "${GSIM_TRIXIE:-1}" = 1 ]; } && P="$P debootstrap"
[ "${GSIM_VENV:-1}" = 1 ] && P="$P python3-venv python3-dev"   # spidev on PyPI is an sdist: needs gcc + Python.h
miss=; for p in $P; do dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'ok installed' || miss="$miss $p"; done
[ -z "$miss" ] || apt-get install -y --no-install-recommends $miss

step "download kernel image/headers/source (one consistent version)"
KVER=${GSIM_KVER:-$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-/{sub("linux-image-","",$2);print $2;exit}')}
ABI=${KVER%-amd64}; SER=$(echo "$ABI" | cut -d. -f1,2)          # 6.1.0-56-amd64 -> 6.1.0-56 -> 6.1
V=$(apt-cache policy "linux-image-$KVER" | awk '/Candidate:/{print $2}')
echo "kernel $KVER, package version $V"
cd "$C/debs"
apt-get -o APT::Sandbox::User=root download "linux-image-$KVER=$V" "linux-headers-$KVER=$V" "linux-headers-$ABI-common=$V" \
  "linux-kbuild-$SER=$V" "linux-source-$SER=$V" busybox-static

step "extract"
dpkg-deb -x linux-image-"$KVER"_"$V"_*.deb "$X/img"
cp "$X/img/boot/vmlinuz-$KVER" "$C/vmlinuz"
# also unpack the xz payload of the bzImage (a stripped ELF vmlinux with a PVH entry note): QEMU boots it
# directly (PVH), which skips ~2.5 s of in-guest decompression under TCG. xz complains about trailing data.
off=$(LC_ALL=C grep -obUaP '\xfd7zXZ\x00' "$C/vmlinuz" | head -1 | cut -d: -f1)
tail -c +$((${off:-0} + 1)) "$C/vmlinuz" | xz -dcq > "$C/vmlinux" 2>/dev/null || true
readelf -n "$C/vmlinux" 2>/dev/null | grep -q 'note type: (0x00000012)' || rm -f "$C/vmlinux"  # no PVH note -> use bzImage
for d in linux-headers-"$KVER"_"$V"_*.deb linux-headers-"$ABI"-common_"$V"_*.deb linux-kbuild-"$SER"_"$V"_*.deb; do
  dpkg-deb -x "$d" "$X/hdr"; done
KB=$X/hdr/usr/src/linux-headers-$KVER
sed -i "s|^include /usr/src/|include $X/hdr/usr/src/|" "$KB/Makefile"   # point at the extracted -common tree
dpkg-deb -x busybox-static_*.deb "$X/bb"
S=linux-source-$SER
dpkg-deb --fsys-tarfile "${S}_${V}_all.deb" | tar -xO "./usr/src/$S.tar.xz" | tar -xJ -C "$X" \
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
  step "debootstrap bookworm rootfs with python3-libgpiod (libgpiod v1 API)"
  rm -rf "$C/rootfs"
  debootstrap --variant=minbase --include=python3-minimal,python3-libgpiod,gpiod,python3-serial,python3-pytest bookworm "$C/rootfs" "$MIRROR" > "$X/debootstrap.log"
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
{ echo "kernel: linux-image-$KVER $V (linux-headers/-common/linux-kbuild-$SER/linux-source-$SER $V)"
  echo "busybox-static: $(dpkg-deb -f "$C"/debs/busybox-static_*.deb Version)"
  echo "qemu: $(qemu-system-x86_64 --version | head -1)"
  [ -d "$C/rootfs" ] && echo "rootfs: bookworm, $(dpkg-query --admindir="$C/rootfs/var/lib/dpkg" -W -f='${Package} ${Version}, ' python3-libgpiod python3.11 gpiod)"
  [ -d "$C/trixie" ] && echo "trixie: $(dpkg-query --admindir="$C/trixie/var/lib/dpkg" -W -f='${Package} ${Version}, ' python3-libgpiod python3.13 gpiod python3-spidev)"
  [ -d "$C/venv" ] && echo "venv: $("$C/venv/bin/python" --version), $("$C/venv/bin/pip" list --format=freeze 2>/dev/null | grep -Ei '^(gpiod|spidev)=' | tr '\n' ' ')"
} | tee "$C/VERSIONS"
[ "${GSIM_KEEP:-0}" = 1 ] || rm -rf "$X" "$C/debs"
step "done: $(du -sh "$C" | cut -f1) in $C"
