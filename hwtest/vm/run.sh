#!/bin/bash
# run.sh [COMMAND...] - boot the gpio-sim VM (QEMU TCG), run COMMAND (one /bin/sh command line) as root in the
# guest, power off, exit with COMMAND's exit status (124: timeout, 255: guest died). No COMMAND: interactive shell.
# The guest has /dev/gpiochip0 (gpio-sim, label sim-bank0), sysfs at /sys/devices/platform/gpio-sim.0/gpiochip0/sim_gpioN/,
# tracefs at /sys/kernel/tracing, debugfs at /sys/kernel/debug. Env knobs:
#   GSIM_CACHE   dir made by build.sh (default ${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm)
#   GSIM_ROOT    host   (default) host / shared read-only + tmpfs overlay; $GSIM_CACHE/venv/bin first in PATH (gpiod v2)
#                rootfs debootstrap bookworm rootfs (python3-libgpiod 1.6.3 = v1 API), read-only + tmpfs overlay
#                trixie debootstrap trixie rootfs (python3-libgpiod 2.x = v2 API, python3-spidev), likewise
#                none   busybox initramfs only
#   GSIM_RW      host dir mounted read-write at the same path in the guest; COMMAND runs there (default: $PWD)
#   GSIM_BANKS   gpio-sim bank sizes (default "16"; "16 8" -> gpiochip0 with 16 lines + gpiochip1 with 8; "none": no chip)
#   GSIM_NAMES   line-name prefix per bank ("GPIO B1_" -> lines GPIO0.. on bank0, B1_0.. on bank1; "-" = no names;
#                "RPI" = a Raspberry Pi's: ID_SDA ID_SCL GPIO2 GPIO3 ...)
#   GSIM_SPI=1   spi-gpio on sim-bank0 lines 0..3 = sck,mosi,miso,cs -> /dev/spidev1.0
#   GSIM_SPI=user  SPI bus 0 whose transfers a program answers through /dev/spi-sim (spi-sim.c) -> /dev/spidev0.0
#   GSIM_MEM (MiB, 1024)  GSIM_SMP (vCPUs, 1: ~15% faster than 2 under TCG here)  GSIM_TIMEOUT (s, 600)  GSIM_APPEND (extra kernel cmdline)
set -uo pipefail
C=${GSIM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/gpio-sim-vm}
[ -f "$C/initrd.img" ] || { echo "run.sh: $C/initrd.img missing, run build.sh first" >&2; exit 2; }
command -v qemu-system-x86_64 >/dev/null || { echo "run.sh: qemu-system-x86_64 missing: apt-get install qemu-system-x86 (build.sh installs it)" >&2; exit 2; }
C=$(cd "$C" && pwd); K=$C/vmlinux; [ -f "$K" ] || K=$C/vmlinuz; ROOT=${GSIM_ROOT:-host}; RW=$(cd "${GSIM_RW:-$PWD}" && pwd) || exit 2
CTL=$(mktemp -d "${TMPDIR:-/tmp}/gsim-ctl.XXXXXX"); trap 'rm -rf "$CTL"' EXIT
q() { printf "'%s'" "$(printf %s "$1" | sed "s/'/'\\\\''/g")"; }   # single-quote for sh
PATHV=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
case $ROOT in
  host)   FS=(-virtfs "local,path=/,mount_tag=root,security_model=none,readonly=on,multidevs=remap"); PATHV=$C/venv/bin:$PATHV;;
  rootfs) FS=(-virtfs "local,path=$C/rootfs,mount_tag=root,security_model=none,readonly=on");;
  trixie) FS=(-virtfs "local,path=$C/trixie,mount_tag=root,security_model=none,readonly=on");;
  none)   FS=(); PATHV=/bin;;
  *) echo "run.sh: GSIM_ROOT must be host, rootfs, trixie or none" >&2; exit 2;;
esac
printf 'GSIM_BANKS=%s\nGSIM_NAMES=%s\nGSIM_SPI=%s\nGSIM_ROOT=%s\nGSIM_RWPATH=%s\n' "$(q "${GSIM_BANKS:-16}")" "$(q "${GSIM_NAMES:-}")" "$(q "${GSIM_SPI:-0}")" \
  "$ROOT" "$(q "${RW%/}")" > "$CTL/env"     # RW=/ -> no rw share
[ $# -gt 0 ] && printf 'export PATH=%s\ncd %s || exit 125\n%s\n' "$(q "$PATHV")" "$(q "$RW")" "$*" > "$CTL/cmd.sh"
Q=(qemu-system-x86_64 -accel tcg -m "${GSIM_MEM:-1024}" -smp "${GSIM_SMP:-1}" -nographic -no-reboot -net none -bios qboot.rom
   -kernel "$K" -initrd "$C/initrd.img" "${FS[@]}"
   -virtfs "local,path=$CTL,mount_tag=gsimctl,security_model=none"
   -append "console=ttyS0 quiet loglevel=3 panic=-1 cryptomgr.notests ${GSIM_APPEND:-}")
[ "$RW" = / ] || Q+=(-virtfs "local,path=$RW,mount_tag=rw,security_model=none,multidevs=remap")
[ $# -eq 0 ] && { "${Q[@]}"; exit 0; }                     # interactive; Ctrl-a x kills qemu
timeout -k 5 "${GSIM_TIMEOUT:-600}" "${Q[@]}" < /dev/null | sed -u 's/\r$//; /^\[ *[0-9.]*\] reboot: Power down$/d'
st=${PIPESTATUS[0]}; [ "$st" = 124 ] && { echo "run.sh: timeout" >&2; exit 124; }
[ -s "$CTL/rc" ] && exit "$(cat "$CTL/rc")"
echo "run.sh: guest did not report an exit status (qemu status $st)" >&2; exit 255
