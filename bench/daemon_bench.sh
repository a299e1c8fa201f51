#!/usr/bin/env bash
# idmd's side-by-side benchmarks (./idm bench; --quick: a few seconds, the CTest entry).
#   1. real-time loop at 10 kHz on the simulated stage vs Debian's cyclictest, same interval:
#      ratio of p99 wake-up latency (target <= 1.5)
#   2. POS? round trip with 8 clients on loopback vs a minimal echo server: p99 ratio (<= 3)
#   3. RSS on the simulated stage over 10,000 moves (<= 50 MB, no growth)
set -euo pipefail
build="${1:?usage: bench/daemon_bench.sh BUILD_DIR [--quick]}"
quick="${2:-}"
src="$(cd "$(dirname "$0")/.." && pwd)"
secs=60; queries=20000; moves=10000
[ "$quick" = "--quick" ] && { secs=2; queries=500; moves=20; }
tmp="$(mktemp -d)"; pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; rm -rf "$tmp"; }
trap cleanup EXIT
sed -e "s#/var/lib/idmd/calibration.txt#$tmp/cal.txt#" -e "s#/var/lib/idmd/data#$tmp/data#" \
  "$src/config/idmd.yaml" > "$tmp/idmd.yaml"
bench="$build/bench/daemon_bench"

echo "== 1. real-time loop, 10 kHz, ${secs} s (SCHED_FIFO 80 when permitted) vs cyclictest -p80 -i100"
"$bench" loop "$secs" 1e-4 "$tmp/idmd.yaml" | tee "$tmp/loop.txt"
if command -v cyclictest >/dev/null; then
  loops=$((secs * 10000))
  cyclictest -m -p80 -i100 -l "$loops" -q -h 64 -t1 > "$tmp/ct.txt" 2>/dev/null || true
  # p99 from cyclictest's 1-us histogram.
  ct_p99=$(awk '/^[0-9]/ {c[$1]=$2; n+=$2} END {acc=0; for (i=0;i<=64;i++) {acc+=c[i]; if (acc>=0.99*n) {print i+1; exit}} print 65}' "$tmp/ct.txt")
  ct_max=$(awk '/# Max Latencies/ {print $4+0}' "$tmp/ct.txt")
  echo "cyclictest p99_us=$ct_p99 max_us=$ct_max"
  idmd_p99=$(sed -n 's/.*p99_us=\([0-9.]*\).*/\1/p' "$tmp/loop.txt")
  awk -v a="$idmd_p99" -v b="$ct_p99" 'BEGIN {printf "p99 ratio idmd/cyclictest = %.2f (target <= 1.5)\n", a/b}'
else
  echo "cyclictest not installed (rt-tests)"
fi

echo "== 2. POS? round trip, 8 clients x ${queries} queries, idmd vs echo server"
"$build/daemon/idmd" --config "$tmp/idmd.yaml" --port 0 --unix "" > "$tmp/idmd.out" 2>"$tmp/idmd.err" &
pids+=($!)
"$bench" echo > "$tmp/echo.out" &
pids+=($!)
for _ in $(seq 100); do grep -q listening "$tmp/idmd.out" && grep -q listening "$tmp/echo.out" && break; sleep 0.1; done
port=$(sed -n 's/.*127.0.0.1:\([0-9]*\).*/\1/p' "$tmp/idmd.out")
eport=$(sed -n 's/.*127.0.0.1:\([0-9]*\).*/\1/p' "$tmp/echo.out")
"$bench" rtt "$port" 8 "$queries" | sed 's/^/idmd /' | tee "$tmp/rtt.txt"
"$bench" rtt "$eport" 8 "$queries" | sed 's/^/echo /' | tee -a "$tmp/rtt.txt"
awk '/^idmd/ {for(i=1;i<=NF;i++) if ($i ~ /^p99_us=/) {split($i,a,"="); d=a[2]}}
     /^echo/ {for(i=1;i<=NF;i++) if ($i ~ /^p99_us=/) {split($i,a,"="); e=a[2]}}
     END {printf "p99 ratio idmd/echo = %.2f (target <= 3)\n", d/e}' "$tmp/rtt.txt"

echo "== 3. RSS over ${moves} moves of 1 um on the simulated stage"
"$bench" rss "$moves" "$tmp/idmd.yaml"
