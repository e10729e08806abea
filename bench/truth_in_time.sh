#!/usr/bin/env bash
# Truth in time: runs one schedule on the demo station (config/demo.toml,
# three DUTs and a rate table) through gyrotherm-sim and gyrothermd at a time
# scale, optionally beside busy processes, and prints what was stored against
# the simulator's truth (bench/truth_in_time.py): Table I rows present and
# their n, bias errors in sigmas of the mean, scale factors, wall time and
# the effective time scale. bench/README.md, "Truth in time".
#
#   bench/truth_in_time.sh [--bin DIR] [--scale X] [--hogs N] [--scaled-clock]
#                          [--out DIR] SCHEDULE
#
# --bin DIR       the binaries (default build/bin); an older build measures
#                 the "before" figures the same way
# --scaled-clock  each process scales wall time alone (the simulator with
#                 --scaled-clock when it knows it, the daemon with
#                 --clock scaled when it knows it); builds since the one
#                 clock refuse this above x10, so above it this measures
#                 an older build's "before" (--bin)
# --hogs N        N `yes > /dev/null` beside the station (a loaded machine)
set -euo pipefail
cd "$(dirname "$0")/.."

bin=build/bin scale=100 hogs=0 scaled=0 out=""
while [ $# -gt 1 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --scale) scale=$2; shift 2 ;;
    --hogs) hogs=$2; shift 2 ;;
    --scaled-clock) scaled=1; shift ;;
    --out) out=$2; shift 2 ;;
    *) echo "truth_in_time: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
[ $# -eq 1 ] || { sed -n '2,19p' "$0"; exit 2; }
schedule=$(realpath "$1")
bin=$(realpath "$bin")
out=${out:-$(mktemp -d /tmp/truth-in-time.XXXXXX)}
mkdir -p "$out"
out=$(realpath "$out")

port=$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
sed -e "s|^db = .*|db = \"$out/station.db\"|" \
    -e "s|^endpoints_file = .*|endpoints_file = \"$out/endpoints.toml\"|" \
    -e "s|^truth_file = .*|truth_file = \"$out/truth.json\"|" \
    -e "s|^gyro_link = .*|gyro_link = \"$out/gyro-pty\"|" \
    -e "s|^control_socket = .*|control_socket = \"$out/sim.sock\"|" \
    -e "s|^directory = .*|directory = \"$out/reports\"|" \
    -e "s|^port = 8750|port = $port|" \
    config/demo.toml >"$out/station.toml"

pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
}
trap cleanup EXIT
for _ in $(seq 1 "$hogs"); do
  sh -c 'exec yes >/dev/null' &
  pids+=($!)
done

sim_args=(--config "$out/station.toml" --time-scale "$scale")
daemon_args=(--config "$out/station.toml" --schedule "$schedule" --time-scale "$scale" --exit-when-done)
if [ $scaled -eq 0 ]; then
  "$bin/gyrothermd" --help 2>/dev/null | grep -q -- --clock && daemon_args+=(--clock sim)
else
  "$bin/gyrotherm-sim" --help 2>/dev/null | grep -q -- --scaled-clock && sim_args+=(--scaled-clock)
  "$bin/gyrothermd" --help 2>/dev/null | grep -q -- --clock && daemon_args+=(--clock scaled)
fi
start=$(date +%s.%N)
"$bin/gyrotherm-sim" "${sim_args[@]}" >"$out/sim.log" 2>&1 &
sim_pid=$!
pids+=($sim_pid)
"$bin/gyrothermd" "${daemon_args[@]}" >"$out/daemon.log" 2>&1 && rc=0 || rc=$?
end=$(date +%s.%N)
sim_status=$("$bin/gyrotherm-sim" ctl --socket "$out/sim.sock" status 2>/dev/null | sed 's/^ok //' || true)
echo "daemon exit $rc; files in $out"
/usr/bin/python3 bench/truth_in_time.py --db "$out/station.db" --truth "$out/truth.json" \
  --config "$out/station.toml" --wall-s "$(echo "$end - $start" | bc)" --scale "$scale" \
  --hogs "$hogs" --sim-status "$sim_status"
