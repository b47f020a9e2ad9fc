#!/bin/sh
# Runs inside the booted test root (report.service). Every wait has a deadline.
i=0
while [ "$(systemctl show -P SubState motorctld)" != running ] && [ $i -lt 60 ]; do
  sleep 0.5; i=$((i + 1))
done
sleep 3  # let STATUS= arrive
systemctl show motorctld -p ActiveState,SubState,StatusText,NRestarts,User
echo "pty: $(stat -L -c '%A %U %G' /run/motorctl/motorctl.pty)"
echo "client: $(su -s /bin/sh -c 'motorctl -p /run/motorctl/motorctl.pty pos 0' motorctl 2>&1)"
echo "status-socket: $(su -s /bin/sh -c 'motorctld --status --state-dir /run/motorctl' motorctl \
  | grep -c '"motors"')"
systemctl stop motorctld
echo "after-stop: $(systemctl show -P ActiveState motorctld) $(systemctl show -P Result motorctld)"
echo "left-in-run: $(ls -A /run/motorctl | tr '\n' ' ')"
# The config switch to keep state across reboots: /var/lib/motorctl (StateDirectory=).
sed -i 's|^directory = ""|directory = "/var/lib/motorctl"|' /etc/motorctl/motorctl.toml
systemctl start motorctld
i=0
while [ "$(systemctl show -P SubState motorctld)" != running ] && [ $i -lt 60 ]; do
  sleep 0.5; i=$((i + 1))
done
echo "var-lib: $(systemctl show -P SubState motorctld) $(ls -A /var/lib/motorctl | tr '\n' ' ')"
systemctl stop motorctld
journalctl -u motorctld --no-pager -o verbose | grep -c '^ *SIGNAL=SIGTERM$' | sed 's/^/journal-fields: /'
journalctl -u motorctld --no-pager | sed 's/^/  | /'
systemctl poweroff
