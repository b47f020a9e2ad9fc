#!/bin/busybox sh
# /init of the gpio-sim test VM (busybox initramfs built by build.sh). Settings come from the 9p share
# "gsimctl" (written by run.sh): env (variables below) and cmd.sh (the command). Exit status -> gsimctl/rc.
/bin/busybox --install -s /bin
export PATH=/bin HOME=/root
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev
M=/lib/modules
for m in $(cat $M/base.list); do insmod $M/$m || echo "gsim: insmod $m failed"; done
P9=trans=virtio,version=9p2000.L,msize=512000
mkdir -p /ctl; mount -t 9p -o $P9 gsimctl /ctl || { echo "gsim: no gsimctl share"; poweroff -f; }
. /ctl/env   # GSIM_BANKS GSIM_NAMES GSIM_SPI GSIM_ROOT GSIM_RWPATH
# gpio-sim: one chip, one bank (-> /dev/gpiochipN, label sim-bankN) per number in GSIM_BANKS
# ("none": no chip; the guest's tests make their own, hwtest/boards.py)
mount -t configfs none /sys/kernel/config
if [ "$GSIM_BANKS" != none ]; then
C=/sys/kernel/config/gpio-sim/chip0; mkdir $C; i=0
for n in ${GSIM_BANKS:-16}; do
  mkdir $C/bank$i; echo $n > $C/bank$i/num_lines; echo sim-bank$i > $C/bank$i/label
  # GSIM_NAMES: one line-name prefix per bank ("GPIO B1_" -> GPIO0.. on bank0, B1_0.. on bank1; "-" = none;
  # "RPI": a Raspberry Pi's header names, ID_SDA ID_SCL GPIO2 GPIO3 ...)
  set -- ${GSIM_NAMES:-}; shift $i 2>/dev/null && p=${1:--} || p=-
  [ "$p" != - ] && j=0 && while [ $j -lt $n ]; do
    name=$p$j; [ "$p" = RPI ] && { name=GPIO$j; [ $j = 0 ] && name=ID_SDA; [ $j = 1 ] && name=ID_SCL; }
    mkdir $C/bank$i/line$j; echo $name > $C/bank$i/line$j/name; j=$((j+1)); done
  i=$((i+1))
done
echo 1 > $C/live || echo "gsim: gpio-sim chip0 failed to go live"
fi
# optional bit-banged SPI bus 1 on sim-bank0 lines 0..3 (sck mosi miso cs) -> /dev/spidev1.0
[ "$GSIM_SPI" = 1 ] && for m in $(cat $M/spi.list); do insmod $M/$m || echo "gsim: insmod $m failed"; done
# or SPI bus 0 answered by a program through /dev/spi-sim (spi-sim.c's user=1) -> /dev/spidev0.0
[ "$GSIM_SPI" = user ] && { insmod $M/spi-sim.ko user=1 bus=0 || echo "gsim: insmod spi-sim.ko user=1 failed"; }
R=/
if [ "$GSIM_ROOT" != none ]; then
  # 9p root shared read-only by the host + tmpfs overlay: writable in the guest, changes are discarded
  mkdir -p /lower /upper /newroot; R=/newroot
  mount -t 9p -o $P9,ro,cache=loose root /lower || { echo "gsim: root mount failed"; poweroff -f; }
  mount -t tmpfs -o mode=755 upper /upper; mkdir /upper/u /upper/w
  mount -t overlay -o lowerdir=/lower,upperdir=/upper/u,workdir=/upper/w overlay $R || { echo "gsim: overlay failed"; poweroff -f; }
  mount -t proc proc $R/proc; mount -t sysfs sys $R/sys; mount -t devtmpfs dev $R/dev
  mount -t configfs none $R/sys/kernel/config
  mkdir -p $R/dev/pts $R/dev/shm; mount -t devpts devpts $R/dev/pts; mount -t tmpfs shm $R/dev/shm
fi
mount -t tracefs nodev $R/sys/kernel/tracing; mount -t debugfs nodev $R/sys/kernel/debug
# host directory shared read-write at the same path (the test's working dir)
[ -n "$GSIM_RWPATH" ] && mkdir -p "$R$GSIM_RWPATH" && mount -t 9p -o $P9 rw "$R$GSIM_RWPATH"
mkdir -p $R/run/gsim && mount --bind /ctl $R/run/gsim
if [ -s /ctl/cmd.sh ]; then chroot $R /bin/sh /run/gsim/cmd.sh; echo $? > /ctl/rc
else setsid -c chroot $R /bin/sh -l; fi
sync; poweroff -f
