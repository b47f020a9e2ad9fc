#!/bin/sh
# Runs inside the booted test root (report.service). Every wait has a deadline: 2 minutes,
# for a root that runs under qemu-user (tools/debroot.sh); a native one is there in seconds.
i=0
while [ "$(systemctl show -P SubState motorctld)" != running ] && [ $i -lt 240 ]; do
  sleep 0.5; i=$((i + 1))
done
sleep 3  # let STATUS= arrive
systemctl show motorctld -p ActiveState,SubState,StatusText,NRestarts,User
echo "pty: $(stat -L -c '%A %U %G' /run/motorctl/motorctl.pty)"
echo "client: $(su -s /bin/sh -c 'motorctl -p /run/motorctl/motorctl.pty pos 0' motorctl 2>&1)"
echo "status-socket: $(su -s /bin/sh -c 'motorctld --status --state-dir /run/motorctl' motorctl \
  | grep -c '"motors"')"
echo "step-core: $(su -s /bin/sh -c 'motorctld --status --state-dir /run/motorctl' motorctl \
  | python3 -c 'import json, sys; print(json.load(sys.stdin)["executor"]["core"])')"
systemctl stop motorctld
echo "after-stop: $(systemctl show -P ActiveState motorctld) $(systemctl show -P Result motorctld)"
echo "left-in-run: $(ls -A /run/motorctl | tr '\n' ' ')"
# The config switch to keep state across reboots: /var/lib/motorctl (StateDirectory=).
sed -i 's|^directory = ""|directory = "/var/lib/motorctl"|' /etc/motorctl/motorctl.toml
systemctl start motorctld
i=0
while [ "$(systemctl show -P SubState motorctld)" != running ] && [ $i -lt 240 ]; do
  sleep 0.5; i=$((i + 1))
done
echo "var-lib: $(systemctl show -P SubState motorctld) $(ls -A /var/lib/motorctl | tr '\n' ' ')"
systemctl stop motorctld
journalctl -u motorctld --no-pager -o verbose | grep -c '^ *SIGNAL=SIGTERM$' | sed 's/^/journal-fields: /'
journalctl -u motorctld --no-pager | sed 's/^/  | /'

# Two instances of the template at once: each its own config (/etc/motorctl/NAME.toml, its
# executor on its own CPU), serving place (right: from /etc/default/motorctld-right) and state
# (left: /run/motorctl-left; right: kept across reboots in /var/lib/motorctl-right).
cpus=$(nproc)
for i in left right; do
  cpu=0; [ $i = right ] && [ "$cpus" -gt 1 ] && cpu=1
  dir=; [ $i = right ] && dir=/var/lib/motorctl-right
  # The container cannot give the executors SCHED_FIFO (no CAP_SYS_RESOURCE to raise
  # RLIMIT_RTPRIO), so their timing is best effort on a busy machine: the embedded default's
  # simulated motors slide late steps and never fault for it; this checks the units,
  # bench/instances.py the timing.
  motorctld --print-default-config | sed -e "s/^cpu = -1$/cpu = $cpu/" \
    -e "s|^directory = \"\"|directory = \"$dir\"|" > /etc/motorctl/$i.toml
done
echo 'MOTORCTLD_SERVE="--pty /run/motorctl-right/host.pty"' > /etc/default/motorctld-right
systemctl enable --now motorctld@left motorctld@right 2>&1 | sed 's/^/  | /'
for i in left right; do
  n=0
  while [ "$(systemctl show -P SubState motorctld@$i)" != running ] && [ $n -lt 240 ]; do
    sleep 0.5; n=$((n + 1))
  done
done
for i in left right; do
  pty=/run/motorctl-$i/motorctl.pty; [ $i = right ] && pty=/run/motorctl-right/host.pty
  target=100; [ $i = right ] && target=200
  echo "instance $i: $(systemctl show -P ActiveState motorctld@$i) $(systemctl show -P SubState motorctld@$i) NRestarts=$(systemctl show -P NRestarts motorctld@$i)"
  echo "instance $i pty: $(stat -L -c '%A %U %G' $pty) $pty"
  su -s /bin/sh -c "motorctl -p $pty moveto 0 $target && motorctl -p $pty wait 0" motorctl \
    | sed "s/^/  instance $i: /"
  echo "instance $i client: $(su -s /bin/sh -c "motorctl -p $pty pos 0" motorctl 2>&1)"
  pid=$(su -s /bin/sh -c "motorctld --status --state-dir /run/motorctl-$i" motorctl \
    | python3 -c 'import json, sys; print(json.load(sys.stdin)["executor"]["pid"])')
  echo "instance $i executor cpus: $(sed -n 's/^Cpus_allowed_list:\t*//p' /proc/$pid/status)"
  echo "instance $i run: $(ls /run/motorctl-$i | grep -v '\.pty$' | tr '\n' ' ' | sed 's/ $//')"
  [ $i = right ] && echo "instance $i var-lib: $(ls /var/lib/motorctl-$i | tr '\n' ' ' | sed 's/ $//')"
done
systemctl stop motorctld@left motorctld@right
echo "instances after stop: $(systemctl show -P ActiveState motorctld@left) $(systemctl show -P ActiveState motorctld@right)"
journalctl -u motorctld@left -u motorctld@right --no-pager | sed 's/^/  | /'
# what the admin made goes before the package is purged (dpkg keeps /etc/motorctl otherwise)
systemctl disable --quiet motorctld@left motorctld@right
rm -f /etc/motorctl/left.toml /etc/motorctl/right.toml /etc/default/motorctld-right
# A USB serial adapter that appears late: motorctld@late serves a --port device that is not
# there when the service starts; 30 s later it appears (a socat PTY pair, named as udev names
# an adapter, /dev/serial/by-id/...) and a command is answered, with no manual step.
late=/dev/serial/by-id/usb-motorctl_late_test-if00-port0
motorctld --print-default-config > /etc/motorctl/late.toml
echo "MOTORCTLD_SERVE=\"--port $late\"" > /etc/default/motorctld-late
systemctl start motorctld@late
n=0
while [ "$(systemctl show -P SubState motorctld@late)" != running ] && [ $n -lt 240 ]; do
  sleep 0.5; n=$((n + 1))
done
sleep 3  # let STATUS= arrive
echo "late before: $(systemctl show -P SubState motorctld@late) $(systemctl show -P StatusText \
  motorctld@late | sed -n 's/.*\(WAITING FOR SERIAL DEVICE [^ ]*\).*/\1/p')"
sleep 30
mkdir -p /dev/serial/by-id
socat "pty,raw,echo=0,link=$late,group=motorctl,perm=0660" pty,raw,echo=0,link=/root/late-host \
  2>/dev/null &
socat_pid=$!
n=0
while [ ! -e /root/late-host ] && [ $n -lt 120 ]; do sleep 0.25; n=$((n + 1)); done
echo "late client: $(timeout 60 motorctl -p /root/late-host pos 0 2>&1)"
echo "late after: $(systemctl show -P SubState motorctld@late) NRestarts=$(systemctl show -P \
  NRestarts motorctld@late)"
said() { journalctl -u motorctld@late --no-pager -o cat | grep -c "$1"; }
echo "late journal: $(said 'is not there: serving it as soon as it appears') $(said 'is there after')"
systemctl stop motorctld@late
kill "$socat_pid"
journalctl -u motorctld@late --no-pager | sed 's/^/  | /'
rm -f /etc/motorctl/late.toml /etc/default/motorctld-late
systemctl poweroff
