#!/usr/bin/env bash
# bench/hil-latency.sh BUILD_DIR [PERIODS]: the lockstep period through pmsm-thermald against
# the floor of the bus, in one boot of the same (virtual) CAN bus:
#
#   scripts/vcan-env -- bench/hil-latency.sh build/release 20000    # in User-Mode Linux
#   bench/hil-latency.sh build/release                             # natively, on vcan0
#
# (a) the floor: two minimal processes (bench/can_latency echo and ping) exchange a 24-byte
#     and a 12-byte CAN FD frame, one read and one write each per exchange;
# (b) the period: pmsm-plant in lockstep and pmsm-thermald (tests/hil/data/hil-daemon.toml,
#     node 1, with a supervisor sending DRIVE_COMMANDs), after start-up.
# One observer process measures both the same way: the kernel's receive timestamps of the ping
# (a) or of SENSOR_SAMPLE (b), whose intervals are one whole exchange or lockstep period.
# Prints both distributions (min, median, p99, p99.9, max, a histogram) as JSON lines and the
# ratios b/a. A measurement: no pass or fail. docs/performance.md has the figures.
# HIL_LATENCY_IO_URING=0 runs the daemon with can.io_uring = false (a send, a poll and a read a
# period instead of one io_uring_enter), to compare the two in one boot.
set -euo pipefail
prog=hil-latency
[ $# -ge 1 ] || { echo "usage: $0 BUILD_DIR [PERIODS]" >&2; exit 2; }
build=$(cd "$1" && pwd)
periods=${2:-20000}
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
iface=${PMSM_CAN_IFACE:-vcan0}
# shellcheck source=../tests/hil/lib.sh
. "$src/tests/hil/lib.sh"
latency=$build/bench/can_latency
thermald=$build/daemon/pmsm-thermald
plant=$build/plant-emulator/pmsm-plant
tool=$build/tools/pmsm-thermal
for b in "$latency" "$thermald" "$plant" "$tool"; do
  [ -x "$b" ] || die "missing executable $b"
done
work=$(mktemp -d "${TMPDIR:-/tmp}/hil-latency.XXXXXXXX")
hil_cleanup_on_exit "$work" "${HIL_LATENCY_KEEP:-0}"
field() { sed -n "s/.*\"$2\": \\([-0-9.e+]*\\).*/\\1/p" <<<"$1"; }

# (a) The floor.
id=$(( ((RANDOM & 0xFFF) << 16) | 0x100 ))  # extended, tagged: runs on a shared bus do not meet
"$latency" observe --id "$id" --count "$periods" > "$work/floor.json" 2>&1 &
observer=$!
pids+=("$observer")
hil_wait_for "$work/floor.json" ready "$observer" 10 "the observer"
"$latency" echo --id "$id" > "$work/echo.log" 2>&1 &
pids+=($!)
hil_wait_for "$work/echo.log" ready "$!" 10 "the echo process"
"$latency" ping --id "$id" --count "$periods" || die "the ping process failed"
wait "$observer" || die "the observer failed: $(tail -2 "$work/floor.json")"
floor=$(tail -1 "$work/floor.json")
echo "floor (two processes, ping-pong): $floor"

# (b) pmsm-plant <-> pmsm-thermald in lockstep.
io_uring=$([ "${HIL_LATENCY_IO_URING:-1}" = 0 ] && echo false || echo true)
sed -e "s/^interface = .*/interface = \"$iface\"\nio_uring = $io_uring/" "$src/tests/hil/data/hil-daemon.toml" > "$work/daemon.toml"
"$thermald" --config "$work/daemon.toml" > "$work/daemon.log" 2>&1 &
daemon=$!
pids+=("$daemon")
hil_wait_for "$work/daemon.log" "ready: waiting" "$daemon" 20 pmsm-thermald
"$tool" command --iface "$iface" --node 1 --mode speed --speed 94 --calibrate-at 25 --period-ms 100 \
  > "$work/command.log" 2>&1 &
pids+=($!)
warmup=5000  # start-up, the ADC offset calibration and the speed ramp are not the steady period
"$latency" observe --standard --id 0x021 --count "$periods" --warmup "$warmup" --timeout-s 30 > "$work/period.json" 2>&1 &
observer=$!
pids+=("$observer")
hil_wait_for "$work/period.json" ready "$observer" 10 "the observer"
duration=$(awk -v n="$((periods + warmup + 2000))" 'BEGIN { printf "%.4f", n * 1e-4 }')
"$plant" --config "$src/tests/hil/data/hil-plant.toml" --iface "$iface" --node 1 --mode lockstep \
  --duration-s "$duration" > "$work/plant.log" 2>&1 || die "pmsm-plant failed: $(tail -3 "$work/plant.log")"
wait "$observer" || die "the observer failed: $(tail -2 "$work/period.json")"
period=$(tail -1 "$work/period.json")
echo "period (pmsm-plant <-> pmsm-thermald, lockstep): $period"
grep -m1 -o "CAN: .*" "$work/daemon.log" || true

ratio() { awk -v a="$(field "$period" "$1")" -v b="$(field "$floor" "$1")" 'BEGIN { printf "%.2f", a / b }'; }
printf '%-8s %10s %10s %8s\n' "" "floor us" "period us" "ratio"
for p in min_us median_us p99_us p999_us max_us; do
  printf '%-8s %10s %10s %8s\n' "${p%_us}" "$(field "$floor" "$p")" "$(field "$period" "$p")" "$(ratio "$p")"
done
ok=1
