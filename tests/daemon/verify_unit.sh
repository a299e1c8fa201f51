#!/usr/bin/env bash
# systemd-analyze verify on the generated idmd.service, with ExecStart pointed at the build's idmd
# (verify wants the binary to exist), plus the directives the unit must keep.
set -euo pipefail
unit="$1"; idmd="$2"
tmp="$(mktemp -d)"; trap 'rm -rf "$tmp"' EXIT
sed "s#^ExecStart=[^ ]*#ExecStart=$idmd#" "$unit" > "$tmp/idmd.service"
out="$(systemd-analyze verify "$tmp/idmd.service" 2>&1)" || { echo "$out"; echo "FAIL: verify"; exit 1; }
if echo "$out" | grep -i "idmd.service"; then echo "FAIL: verify warned about the unit"; exit 1; fi
for d in Type=notify WatchdogSec= Restart=on-failure User=idmd NoNewPrivileges=yes \
         ProtectSystem=strict ReadWritePaths= DeviceAllow= "AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK" \
         LimitMEMLOCK=infinity "RestartPreventExitStatus=2 3" SystemCallFilter=@system-service \
         IPAddressAllow=localhost IPAddressDeny=any After=network-online.target; do
  grep -q "^$d" "$unit" || { echo "FAIL: $d missing"; exit 1; }
done
echo "PASS: systemd-analyze verify"
