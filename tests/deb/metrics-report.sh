#!/bin/sh
# Runs inside the booted test root (metrics-report.service; check-install.sh's metrics block):
# the package's motorctl-metrics units write the textfile, Debian's prometheus-node-exporter
# serves it; what its /metrics says of motorctl goes to the report.
# Every wait has a deadline (2 minutes: a root under qemu-user, tools/debroot.sh, is slow).
wait_for() {  # wait_for UNIT: until it runs (2 minutes at most)
  i=0
  while [ "$(systemctl show -P SubState "$1")" != running ] && [ $i -lt 240 ]; do
    sleep 0.5; i=$((i + 1))
  done
}
wait_for motorctld
wait_for prometheus-node-exporter
# installed disabled by the package; enabled as docs/service.md says
echo "timer before: $(systemctl is-enabled motorctl-metrics.timer)"
systemctl enable --now motorctl-metrics.timer 2>&1 | sed 's/^/  | /'
echo "timer: $(systemctl show -P ActiveState motorctl-metrics.timer)"
systemctl start motorctl-metrics.service  # at once, not 30 s after boot
echo "metrics-service: $(systemctl show -P Result motorctl-metrics.service)"
prom=/var/lib/prometheus/node-exporter/motorctl.prom
echo "textfile: $(stat -c '%U %a' $prom 2>&1) $(grep -c '^motorctl_' $prom 2>&1) samples"
python3 - <<'PY'
import time
import urllib.request

for _ in range(240):  # node_exporter may still be binding its port
    try:
        text = urllib.request.urlopen("http://127.0.0.1:9100/metrics", timeout=5).read().decode()
        break
    except OSError as exc:
        error = exc
        time.sleep(0.5)
else:
    raise SystemExit(f"node_exporter: {error}")
lines = text.splitlines()
for line in lines:
    if line.startswith("node_textfile_scrape_error"):
        print(line)
types = {}
for line in lines:
    if line.startswith("# TYPE motorctl_"):
        _, _, name, kind = line.split()
        types[name] = kind
for name in sorted(types):
    print(f"type {name} {types[name]}")
print("untyped:", sum(1 for kind in types.values() if kind == "untyped"))
samples = [line for line in lines if line.startswith("motorctl_")]
print("samples:", len(samples))
for line in samples:
    if line.startswith(("motorctl_up ", "motorctl_build_info")):
        print(line)
PY
journalctl -u motorctl-metrics.service --no-pager | sed 's/^/  | /'
systemctl disable --quiet --now motorctl-metrics.timer
systemctl poweroff
