#!/usr/bin/env bash
# plant_lockstep_speed.sh BUILD_DIR [PERIODS] [RUNS]: the lockstep figures of docs/hil.md.
#
#   scripts/vcan-env -- tests/hil/plant_lockstep_speed.sh build/dev 20000 3
#
# In the same run (same machine, same load, same bus) it measures
#   - the raw vcan ping-pong (bench/can_pingpong: two threads, raw sockets, none of our code);
#   - pmsm-plant in lockstep answered by tests/hil/plant_command_sender (two processes,
#     SocketCanBus + codec + plant step), without candump on the bus;
# and prints one JSON line per run plus the medians: lockstep periods/s, simulated seconds
# per wall second, median cycle time (sample k received -> sample k+1 received: one whole
# lockstep period) and its ratio to the ping-pong's median round trip in the same run (the
# median of the per-run ratios: host load moves both together). No pass/fail on timing: these are measurements.
set -euo pipefail

[ $# -ge 1 ] || { echo "usage: $0 BUILD_DIR [PERIODS] [RUNS]" >&2; exit 2; }
build=$(cd "$1" && pwd)
periods=${2:-20000}
runs=${3:-3}
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
iface=${PMSM_CAN_IFACE:-vcan0}
plant_bin=$build/plant-emulator/pmsm-plant
sender_bin=$build/tests/plant_command_sender
pingpong_bin=$build/bench/can_pingpong
for b in "$plant_bin" "$sender_bin" "$pingpong_bin"; do
  [ -x "$b" ] || { echo "missing $b" >&2; exit 2; }
done
node=0
if [ "${PMSM_VCAN_MODE:-}" != uml ]; then node=$((RANDOM % 15 + 1)); fi
work=$(mktemp -d "${TMPDIR:-/tmp}/plant-speed.XXXXXXXX")
plant_pid=
cleanup() {
  if [ -n "$plant_pid" ]; then kill -TERM "$plant_pid" 2>/dev/null || true; wait "$plant_pid" 2>/dev/null || true; fi
  rm -rf -- "$work"
}
trap cleanup EXIT

field() { sed -n "s/.*\"$2\": \\([-0-9.e+]*\\).*/\\1/p" <<<"$1"; }
median() { sort -g | awk '{ v[NR] = $1 } END { if (NR % 2) print v[(NR + 1) / 2]; else print (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }

rtts=() cycles=() rates=() ratios=()
for run in $(seq 1 "$runs"); do
  pp=$("$pingpong_bin" --iface "$iface" --count "$periods")
  duration_s=$(awk -v n="$periods" 'BEGIN { printf "%.4f", n / 10000 }')
  "$plant_bin" --mode lockstep --config "$src/plant-emulator/profiles/reference.toml" --iface "$iface" \
    --node "$node" --duration-s "$duration_s" --log-level warn 2>"$work/plant.log" &
  plant_pid=$!
  ls=$("$sender_bin" --iface "$iface" --node "$node" --periods "$periods" --law dc --voltage-V 10)
  wait "$plant_pid" || { echo "pmsm-plant failed: $(cat "$work/plant.log")" >&2; exit 1; }
  plant_pid=
  rtt=$(field "$pp" median_rtt_us)
  cycle=$(field "$ls" median_cycle_us)
  rate=$(field "$ls" periods_per_s)
  ratio=$(awk -v c="$cycle" -v r="$rtt" 'BEGIN { printf "%.2f", c / r }')
  rtts+=("$rtt") cycles+=("$cycle") rates+=("$rate") ratios+=("$ratio")
  echo "{\"run\": $run, \"cycle_over_rtt\": $ratio, \"pingpong\": $pp, \"lockstep\": $ls}"
done
m_rtt=$(printf '%s\n' "${rtts[@]}" | median)
m_cycle=$(printf '%s\n' "${cycles[@]}" | median)
m_rate=$(printf '%s\n' "${rates[@]}" | median)
m_ratio=$(printf '%s\n' "${ratios[@]}" | median)
awk -v r="$m_rtt" -v c="$m_cycle" -v p="$m_rate" -v q="$m_ratio" -v n="$periods" -v k="$runs" -v mode="${PMSM_VCAN_MODE:-unknown}" 'BEGIN {
  printf "{\"summary\": true, \"vcan_mode\": \"%s\", \"periods\": %d, \"runs\": %d, \"median_pingpong_rtt_us\": %.1f, \"median_lockstep_cycle_us\": %.1f, \"median_cycle_over_rtt\": %.2f, \"median_lockstep_periods_per_s\": %.0f, \"sim_s_per_wall_s\": %.3f}\n", mode, n, k, r, c, q, p, p / 10000 }'
