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
# The line's clock says which it is: the daemon's uptime until a PLANT_STATUS comes, then the
# plant's simulated time, and the switch is told.
grep -q "^node  0  uptime " "$work/out" || fail "the daemon's uptime not labelled"
grep -q "node 0: a plant emulator is on the bus" "$work/out" || fail "the switch to the plant's time not told"
grep -q "^node  0  plant    3600.5 s" "$work/out" || fail "the plant's time not labelled"

# A node the capture never speaks for is told, not summarised as nothing.
"$exe" monitor --log "$log" --node 2 > "$work/out"
grep -q "no frame of node 2 (--node) was seen" "$work/out" || fail "a node without frames not told"
# The status line shows the shaft's speed and torque from DRIVE_STATUS (MotionValid set).
"$exe" monitor --log "$log" > "$work/out"
grep -q "RUNNING  limit 45 A  314.2 rad/s 20.8 Nm" "$work/out" || fail "DRIVE_STATUS's speed and torque not shown"

# The capture with LINES appended, through the monitor into $work/out.
#   monitor_with LINE...
monitor_with() {
  { cat "$log"; printf '%s\n' "$@"; } > "$work/appended.log"
  "$exe" monitor --log "$work/appended.log" > "$work/out"
}
hb_restarted="(1795493853.589724) vcan0 140#32000000022B0000"  # HEARTBEAT, uptime 0.5 s (was 3600.5 s)

# RECEIVE_STATUS counts modulo 256: a second one a second later whose CommandsAccepted went
# 12 -> 5 (249 more: it wrapped) and RejectedCrc 3 -> 4 is summed, not read as it stands.
monitor_with "(1795493853.618043) vcan0 150#0504050402010100"
grep -q "node  0  daemon: 261 command(s) accepted, 8 frame(s) rejected" "$work/out" || fail "RECEIVE_STATUS's counts not unwrapped"

# A daemon that started again (HEARTBEAT's uptime 3600.5 -> 0.5 s) counts from zero: its
# RECEIVE_STATUS 5 accepted / 1 CRC rejection adds 5 and 1 (not 249 and 254 + ... as a wrap).
monitor_with "$hb_restarted" "(1795493853.618043) vcan0 150#0504050100000000"
grep -q "node 0: the daemon started again (uptime 0.5 s after 3600.5 s)" "$work/out" || fail "a daemon restart not told"
grep -q "node  0  daemon: 17 command(s) accepted, 8 frame(s) rejected" "$work/out" || fail "a restart's counts read as a wrap"
# The restarted daemon reports a rejection (3 accepted, 1 CRC) before its first HEARTBEAT: read
# as a wrap at first, undone when the HEARTBEAT tells the restart.
monitor_with "(1795493853.500000) vcan0 150#0504030100000000" "$hb_restarted" "(1795493853.618043) vcan0 150#0504050100000000"
grep -q "node  0  daemon: 17 command(s) accepted, 8 frame(s) rejected" "$work/out" || fail "an early report of a restarted daemon counted twice"
# The old daemon's own last report (13 accepted, 1 more CRC rejection, 0.2 s after its last
# HEARTBEAT's) stays; the new daemon (up 0.5 s at 1795493853.5897) reports before its first
# HEARTBEAT and is undone: 13 + 5 accepted, 7 + 1 + 1 rejected.
monitor_with "(1795493852.818043) vcan0 150#05040D0402010100" "(1795493853.500000) vcan0 150#0504030100000000" \
  "$hb_restarted" "(1795493853.618043) vcan0 150#0504050100000000"
grep -q "node  0  daemon: 18 command(s) accepted, 9 frame(s) rejected" "$work/out" || fail "the old daemon's last report undone with the new one's"

# A replayed DRIVE_COMMAND (same alive counter) and one with a corrupted CRC.
drive=$(grep -m1 " 040#" "$log")
{
  cat "$log"
  echo "$drive"
  echo "${drive/040#7B/040#7C}"
} > "$work/bad.log"
"$exe" monitor --log "$work/bad.log" > "$work/out"
grep -q "monitor: frame 0x040 fails this monitor's check: repeated_counter" "$work/out" || fail "a replayed command was not flagged"
grep -q "monitor: frame 0x040 fails this monitor's check: bad_crc" "$work/out" || fail "a corrupt command was not flagged"
grep -q "2 not decodable (bad_crc 1, repeated_counter 1)" "$work/out" || fail "the summary does not count both"
# The deadline misses: HEARTBEAT's count since start where it says more than the LOOP_TIMING
# windows' sum (each window's count stops at 255; the demo's summary said "at least 5355" of
# about 200,000).
monitor_with "(1795493853.589724) vcan0 140#D67E0500022BE803"
grep -q ", 1000 deadline miss(es) since the daemon started (HEARTBEAT)" "$work/out" ||
  fail "HEARTBEAT's deadline misses since start not taken"
# ... and kept when the daemon starts again (its count starts from zero).
monitor_with "(1795493853.589724) vcan0 140#D67E0500022BE803" "$hb_restarted"
grep -q ", 1000 deadline miss(es) since the daemon started" "$work/out" || fail "a restart lost the earlier deadline misses"

# A plant that stopped reporting while the daemon runs on: its last truth is not compared with
# the daemon's later estimates (the demo's last line read "error -52.1": the daemon's model
# cooling the winding through the plant's absence at 400x, against a truth frozen at the stop).
estimate="(1795493852.500898) vcan0 110#15229600E8171700"
printf '%s\n' "$estimate" "(1795493852.589724) vcan0 140#727E0500022A0000" \
  "(1795493852.674761) vcan0 200#6022A217D417C409" "$estimate" > "$work/truth.log"
"$exe" monitor --log "$work/truth.log" --plain > "$work/out"
grep -q "(true   88.0, error  -0.8)" "$work/out" || fail "a fresh truth not compared"
printf '%s\n' "(1795493853.589724) vcan0 140#D67E0500022B0000" "(1795493854.589724) vcan0 140#3A7F0500022C0000" \
  "$estimate" >> "$work/truth.log"
"$exe" monitor --log "$work/truth.log" --plain > "$work/out"
grep -q "the plant's last truth 88.0, about 2 s of the daemon's time ago: not compared" "$work/out" ||
  fail "a truth the plant stopped sending shown against later estimates"
grep -q "1 calibrated estimates" "$work/out" || fail "an estimate scored against a truth the plant stopped sending"

# With the power stage's samples on the bus, an estimate is compared with the truth at its own
# sample (interpolated between the truth frames around it), and the line shows that comparison,
# the summary's: not the estimate against a truth frame older than it (which read -0.8 and
# -2.8 C here where the estimate's own error is -1.75 C).
sample() { echo "($1) vcan0 020##4${2}030000CD009AFF99FF0020FF0C00000000000001000000"; }
est_line="vcan0 110#15229600E8171700"
{ sample 1.000 E9; echo "(1.001) vcan0 200#6022A217D417C409"; sample 1.002 EA; echo "(1.003) $est_line"
  sample 1.004 EB; echo "(1.005) vcan0 200#2823A217D417C409"; sample 1.006 EC; echo "(1.007) $est_line"; } > "$work/seq.log"
"$exe" monitor --log "$work/seq.log" --plain --every 0 > "$work/out"
grep -q "(true   89.0, error  -1.8)" "$work/out" || fail "the line does not show the estimate against the truth at its sample"
grep -q "error  -0.8)\|error  -2.8)" "$work/out" && fail "an estimate shown against a truth frame older than it"
grep -q "1 calibrated estimates, error RMS 1.75 C" "$work/out" || fail "the summary's comparison moved"
# A newer estimate waiting for its truth: the line says which estimate its error is of.
{ cat "$work/seq.log"; sample 1.008 ED; echo "(1.009) vcan0 110#60229600E8171700"; } > "$work/seq2.log"
"$exe" monitor --log "$work/seq2.log" --plain --every 0 > "$work/out"
grep -q "winding   88.0 +-  1.5 C (last compared 87.2: true   89.0, error  -1.8)" "$work/out" ||
  fail "an error shown beside a newer estimate without saying which estimate it is of"

# --node: another axis's frames (here node 0's, with node 3's HEARTBEAT beside them) stay out
# of the summary, its checks included.
heartbeat=$(grep -m1 " 140#" "$log")
{
  cat "$log"
  echo "${heartbeat/ 140#/ 143#}"
} > "$work/two.log"
"$exe" monitor --log "$work/two.log" --node 3 --min-estimates 0 > "$work/out"
grep -q "^node  3 " "$work/out" || fail "--node 3 does not show node 3"
if grep -q "^node  0 " "$work/out"; then fail "--node 3 shows node 0"; fi
"$exe" monitor --log "$work/two.log" > "$work/out"
grep -q "^node  0 " "$work/out" && grep -q "^node  3 " "$work/out" || fail "without --node, not both axes are shown"
# A line without an end is cut at 4096 characters and the rest of it skipped (not read into
# memory whole): one line that is no frame, and the capture around it read.
{ cat "$log"; head -c 1000000 /dev/zero | tr '\0' 'A'; echo; cat "$log"; } > "$work/long.log"
"$exe" monitor --log "$work/long.log" > "$work/out"
grep -q "^1 line(s) were not candump frames" "$work/out" || fail "an overlong line not counted as one"
"$exe" monitor --log "$work/long.log" 2>&1 >/dev/null | grep -q "^monitor: line 18 is not a candump frame: " ||
  fail "the line that is no frame not named on standard error"
grep -q "^34 frame(s)" "$work/out" || fail "the capture after an overlong line not read (17 frames each side)"
# What is no capture, or no bound, is refused by name, not read as an empty log or a check that
# every run passes (exit 2).
refused() {  # refused EXPECTED_TEXT ARGS...
  local want=$1
  shift
  local status=0
  "$exe" monitor "$@" > "$work/out" 2>&1 || status=$?
  [ "$status" -eq 2 ] || fail "monitor $*: exit $status, expected 2"
  grep -qF -- "$want" "$work/out" || fail "monitor $*: no '$want'"
}
cp "$log" "$work/own.log"
refused "would write over the log it reads" --log "$work/own.log" --csv "$work/./own.log"
cmp -s "$log" "$work/own.log" || fail "monitor --csv over its --log changed the log"
refused "--csv: expected a file name, got an empty one" --log "$log" --csv ""
printf 'not a frame\n\177ELF binary\n' > "$work/junk.log"
refused "monitor: no line of '$work/junk.log' is a candump frame: not a capture" --log "$work/junk.log"
refused "monitor: '$work' is a directory, not a file" --log "$work"
refused "monitor: standard input is a directory, not a file" --log - < "$work"
refused "--check-rms: expected a number, got 'nan'" --log "$log" --check-rms nan
refused "--check-max: must be >= 0, got -1" --log "$log" --check-max -1
refused "--threshold: expected a number, got 'nan'" --log "$log" --threshold nan
refused "--min-estimates: must be >= 0, got -1" --log "$log" --min-estimates -1
refused "--duration: must be > 0, got -5" vcan0 --duration -5
refused "--log excludes --duration" --log "$log" --duration 5
# A check with nothing to check fails (exit 1): an empty capture, and one whose axis has no
# truth to compare with, passed --check-rms before.
: > "$work/empty.log"
status=0
"$exe" monitor --log "$work/empty.log" --check-rms 1 > "$work/out" 2>&1 || status=$?
[ "$status" -eq 1 ] || fail "an empty capture passed --check-rms (exit $status)"
grep -q "CHECK FAILED: no axis seen" "$work/out" || fail "an empty capture's failed check not named"
status=0
"$exe" monitor --log "$work/empty.log" > "$work/out" 2>&1 || status=$?
[ "$status" -eq 0 ] || fail "an empty capture without a check: exit $status, expected 0 (a capture of nothing)"
status=0
"$exe" monitor --log "$log" --check-rms 100 > "$work/out" 2>&1 || status=$?
[ "$status" -eq 1 ] || fail "a capture with no compared estimate passed --check-rms (exit $status)"
grep -q "CHECK FAILED: node 0 has no compared estimate" "$work/out" || fail "the axis without a compared estimate not named"
echo "monitor_log: ok"
