#!/usr/bin/env bash
# pmsm-thermal monitor on candump logs: it decodes the daemon's RECEIVE_STATUS and LOOP_TIMING,
# and checks the commands it sees as the daemon does (a bad CRC and a replayed alive counter
# are shown as rejections, never as commands).
#   monitor_log.sh SOURCE_DIR PMSM_THERMAL_EXE
set -euo pipefail
src=$1
exe=$2
log=$src/tests/unit/data/candump/protocol_node0.log
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "FAIL: $*"; echo "--- output:"; cat "$work/out"; exit 1; }

# The capture as it is: every frame decodes; the daemon's status frames are summarised.
"$exe" monitor --log "$log" > "$work/out"
grep -q "0 not decodable (none)" "$work/out" || fail "a clean capture has undecodable frames"
grep -q "node  0  daemon: 12 command(s) accepted, 7 frame(s) rejected" "$work/out" || fail "RECEIVE_STATUS not summarised"
grep -q "sample->command median < 16 us, p99 < 64 us; worst 87.3 us" "$work/out" || fail "LOOP_TIMING not summarised"

# A replayed DRIVE_COMMAND (same alive counter) and one with a corrupted CRC.
drive=$(grep -m1 " 040#" "$log")
{
  cat "$log"
  echo "$drive"
  echo "${drive/040#7B/040#7C}"
} > "$work/bad.log"
"$exe" monitor --log "$work/bad.log" > "$work/out"
grep -q "rejected frame 0x040: repeated_counter" "$work/out" || fail "a replayed command was not flagged"
grep -q "rejected frame 0x040: bad_crc" "$work/out" || fail "a corrupt command was not flagged"
grep -q "2 not decodable (bad_crc 1, repeated_counter 1)" "$work/out" || fail "the summary does not count both"
echo "monitor_log: ok"
