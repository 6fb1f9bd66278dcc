#!/usr/bin/env bash
# plant_smoke.sh BUILD_DIR: the pmsm-plant process on a real (virtual) CAN bus, end to end.
#
#   scripts/vcan-env -- tests/hil/plant_smoke.sh build/dev
#
# 1. candump -L records the bus to a file;
# 2. pmsm-plant runs in lockstep on the reference profile for PERIODS periods of simulated
#    time (--duration-s), answered by tests/hil/plant_command_sender (a stand-in controller,
#    not the daemon: a fixed voltage vector, sequence numbers from the samples);
# 3. every captured line is decoded with the project's DBC (pmsm-thermal decode --strict):
#    the test fails on any unknown or undecodable frame, and if SENSOR_SAMPLE,
#    INVERTER_COMMAND, TRUTH_THERMAL, TRUTH_ELECTRICAL or PLANT_STATUS is missing;
# 4. counts per message and the lockstep speed are printed.
#
# Environment: PLANT_SMOKE_PERIODS (default 2000), PLANT_SMOKE_KEEP=1 keeps the work
# directory (it is kept anyway on failure), PMSM_CAN_IFACE (set by vcan-env; default vcan0).
# Under User-Mode Linux the bus is private to this run. On a native, shared vcan the script
# uses a scratch vcan of its own when it may create one, otherwise a random node id and a
# candump filter on it, so that other tests' traffic stays out of the capture.
set -euo pipefail

prog=plant_smoke
die() {
  echo "$prog: FAIL: $*" >&2
  exit 1
}

[ $# -ge 1 ] || { echo "usage: $0 BUILD_DIR" >&2; exit 2; }
build=$(cd "$1" && pwd) || die "no build directory '$1'"
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
periods=${PLANT_SMOKE_PERIODS:-2000}
if ! [[ "$periods" =~ ^[0-9]+$ ]] || [ "$periods" -lt 10 ]; then
  die "PLANT_SMOKE_PERIODS must be a number >= 10"
fi

plant_bin=${PMSM_PLANT_BIN:-$build/plant-emulator/pmsm-plant}
sender_bin=${PMSM_SENDER_BIN:-$build/tests/plant_command_sender}
decode_bin=${PMSM_THERMAL_BIN:-$build/tools/pmsm-thermal}
for b in "$plant_bin" "$sender_bin" "$decode_bin"; do
  [ -x "$b" ] || die "missing executable $b (build the targets pmsm-plant, plant_command_sender, pmsm-thermal)"
done
command -v candump >/dev/null || die "candump is missing (apt-get install can-utils)"
profile=$src/plant-emulator/profiles/reference.toml
dbc=$src/can/pmsm-thermal.dbc

work=$(mktemp -d "${TMPDIR:-/tmp}/plant-smoke.XXXXXXXX")
iface=${PMSM_CAN_IFACE:-vcan0}
node=0
scratch=
candump_pid=
plant_pid=
sender_pid=
ok=0

cleanup() {
  local pid
  for pid in "$sender_pid" "$plant_pid" "$candump_pid"; do
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
      kill -TERM "$pid" 2>/dev/null || true
    fi
  done
  for pid in "$sender_pid" "$plant_pid" "$candump_pid"; do
    if [ -n "$pid" ]; then wait "$pid" 2>/dev/null || true; fi
  done
  if [ -n "$scratch" ]; then ip link del dev "$scratch" 2>/dev/null || true; fi
  if [ "$ok" = 1 ] && [ "${PLANT_SMOKE_KEEP:-0}" != 1 ]; then
    rm -rf -- "$work"
  else
    echo "$prog: work directory kept: $work" >&2
  fi
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# A shared native bus: prefer a private scratch interface; fall back to a random node.
candump_spec=$iface
if [ "${PMSM_VCAN_MODE:-}" != uml ]; then
  name="pmsmsmk$((RANDOM % 10000))"
  if ip link add dev "$name" type vcan 2>/dev/null; then
    scratch=$name
    if ip link set dev "$name" mtu 72 2>/dev/null && ip link set dev "$name" up 2>/dev/null; then
      iface=$name
      candump_spec=$iface
    fi
  fi
  if [ "$iface" != "$scratch" ]; then
    node=$((RANDOM % 15 + 1))
    # Standard IDs of this node only (CAN_EFF_FLAG in the mask selects standard frames).
    candump_spec=$(printf '%s,%03X:8000000F' "$iface" "$node")
  fi
fi
echo "$prog: bus '$iface' (${PMSM_VCAN_MODE:-unknown} mode), node $node, $periods periods, work $work"

# 1. Capture. Wait until candump holds its CAN socket, so the first frames are not missed.
has_socket() {
  local fd
  for fd in "/proc/$1/fd/"*; do
    [[ "$(readlink "$fd" 2>/dev/null)" == socket:* ]] && return 0
  done
  return 1
}
# A large socket buffer (-r, forced as root): under UML candump's writes to the host's file
# system stall it now and then, and a default buffer (~200 CAN FD frames) would overflow.
candump -L -r 16777216 "$candump_spec" >"$work/capture.log" 2>"$work/candump.err" &
candump_pid=$!
for _ in $(seq 1 100); do
  if has_socket "$candump_pid"; then break; fi
  kill -0 "$candump_pid" 2>/dev/null || die "candump exited: $(cat "$work/candump.err")"
  sleep 0.05
done

# 2. Plant and stand-in controller.
duration_s=$(awk -v n="$periods" 'BEGIN { printf "%.4f", n / 10000 }')
"$plant_bin" --mode lockstep --config "$profile" --iface "$iface" --node "$node" \
  --duration-s "$duration_s" >"$work/plant.out" 2>"$work/plant.log" &
plant_pid=$!

t0=$(date +%s.%N)
set +e
timeout 60 "$sender_bin" --iface "$iface" --node "$node" --periods "$periods" --law dc --voltage-V 10 \
  --config "$profile" >"$work/sender.json" 2>"$work/sender.err" &
sender_pid=$!
wait "$sender_pid"
sender_rc=$?
sender_pid=
set -e
t1=$(date +%s.%N)
[ "$sender_rc" = 0 ] || die "the command sender failed (exit $sender_rc): $(cat "$work/sender.err")
plant log:
$(tail -n 20 "$work/plant.log")"

# The plant stops by itself after --duration-s of simulated time.
for _ in $(seq 1 200); do
  kill -0 "$plant_pid" 2>/dev/null || break
  sleep 0.05
done
if kill -0 "$plant_pid" 2>/dev/null; then
  die "pmsm-plant did not stop after ${duration_s} s of simulated time: $(tail -n 5 "$work/plant.log")"
fi
set +e
wait "$plant_pid"
plant_rc=$?
plant_pid=
set -e
[ "$plant_rc" = 0 ] || die "pmsm-plant exited with $plant_rc: $(tail -n 20 "$work/plant.log")"
grep -q 'stopped (duration reached)' "$work/plant.log" || die "no summary line in the plant's log: $(tail -n 5 "$work/plant.log")"

# Let candump drain what is still queued, then stop it (it flushes on SIGINT): a marker frame
# sent now comes after everything the plant sent, so once candump has written it, it has
# written them all (a fixed pause lost the last frames when User-Mode Linux stalled candump).
# Its ID (0x7F0 + node, no message of the protocol) passes the capture's node filter; its line
# is taken out before the strict decode.
marker=$(printf '%03X' $((0x7F0 + node)))
command -v cansend >/dev/null || die "cansend is missing (apt-get install can-utils)"
cansend "$iface" "$marker#00" || die "cansend of the end marker failed"
for _ in $(seq 1 300); do
  grep -q " $marker#00" "$work/capture.log" && break
  sleep 0.1
done
kill -INT "$candump_pid" 2>/dev/null || true
wait "$candump_pid" 2>/dev/null || true
candump_pid=
grep -q " $marker#00" "$work/capture.log" || die "candump did not record the end marker within 30 s"
grep -v " $marker#00" "$work/capture.log" > "$work/capture.tmp" || true
mv "$work/capture.tmp" "$work/capture.log"

# 3. Decode every line with the DBC; --strict fails on anything unknown or undecodable.
set +e
"$decode_bin" decode --strict --dbc "$dbc" "$work/capture.log" >"$work/decoded.txt" 2>"$work/decode.err"
decode_rc=$?
set -e
cat "$work/decode.err"
[ "$decode_rc" = 0 ] || die "pmsm-thermal decode --strict failed (exit $decode_rc); see $work/decoded.txt"

lines=$(wc -l <"$work/capture.log")
[ "$lines" -gt 0 ] || die "candump captured nothing"
count() { grep -c " :: $1(" "$work/decoded.txt" || true; }
echo "$prog: $lines frames captured; per message:"
failed=
for m in SENSOR_SAMPLE INVERTER_COMMAND TRUTH_THERMAL TRUTH_ELECTRICAL PLANT_STATUS; do
  n=$(count "$m")
  printf '  %-18s %8d\n' "$m" "$n"
  [ "$n" -ge 1 ] || failed="$failed $m"
done
[ -z "$failed" ] || die "expected message type(s) missing from the capture:$failed"
samples=$(count SENSOR_SAMPLE)
commands=$(count INVERTER_COMMAND)
if [ "$samples" -le "$periods" ] || [ "$commands" -lt "$periods" ]; then
  # candump (not the plant) lost frames: its socket overflowed. Reported, not failed: the
  # plant's own counters below say whether the exchange itself was complete.
  echo "$prog: note: candump captured $samples samples and $commands commands of at least $((periods + 1)) and $periods sent"
fi

# The stream is the lockstep one: the highest command sequence answers sample PERIODS-1,
# and the last status reports lockstep mode.
max_seq=$(sed -n 's/.* :: INVERTER_COMMAND(Sequence: \([0-9]*\),.*/\1/p' "$work/decoded.txt" | sort -n | tail -n 1)
[ "$max_seq" = "$((periods - 1))" ] || die "the highest INVERTER_COMMAND sequence is $max_seq, not $((periods - 1))"
last_status=$(grep ' :: PLANT_STATUS(' "$work/decoded.txt" | tail -n 1)
[[ "$last_status" == *"Mode: LOCKSTEP"* ]] || die "PLANT_STATUS does not say LOCKSTEP: $last_status"
echo "$prog: last status: ${last_status#* :: }"
grep -q "commands applied $periods," "$work/plant.log" ||
  die "the plant did not apply $periods commands: $(grep -o 'stopped (.*' "$work/plant.log")"

# 4. Figures.
wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.2f", b - a }')
echo "$prog: sender: $(cat "$work/sender.json")"
echo "$prog: plant: $(grep -o 'stopped (.*' "$work/plant.log")"
echo "$prog: PASS ($periods lockstep periods in $wall s including start-up)"
ok=1
