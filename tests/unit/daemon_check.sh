#!/usr/bin/env bash
# pmsm-thermald --check: every shipped configuration passes; a broken one exits 1 and names
# the key and the line.
#   tests/unit/daemon_check.sh SOURCE_DIR THERMALD_EXE
set -uo pipefail
src=$1 exe=$2
fail=0
for f in "$src"/systemd/axis*.toml "$src"/tests/hil/data/*daemon*.toml; do
  [ -e "$f" ] || continue
  if ! out=$("$exe" --config "$f" --check 2>&1); then
    echo "FAIL: $f does not pass --check: $out"
    fail=1
  else
    echo "ok: $out"
  fi
done
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
# bad file, expected exit status, text the message must contain
check_bad() {
  local text=$1 expect=$2 want=$3
  printf '%b' "$text" > "$dir/bad.toml"
  out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
  rc=$?
  if [ "$rc" -ne "$expect" ] || [[ "$out" != *"$want"* ]]; then
    echo "FAIL: expected exit $expect and '$want' for:"; printf '%b\n' "$text"; echo "got exit $rc: $out"
    fail=1
  else
    echo "ok (rejected): $out"
  fi
}
check_bad '[can]\nnode = 22\n' 1 'bad.toml:2: can.node: must be in [0, 15], got 22'
check_bad '[can]\ninterfaec = "vcan0"\n' 1 'can.interfaec'
check_bad '[rt]\npriority = "high"\n' 1 'rt.priority'
check_bad '[supervisor]\ntrip_temp_C = 100\n' 1 'supervisor.trip_temp_C'
check_bad '[supervisor]\ndc_bus_min_V = 700\n' 1 'nominal_dc_bus_V'
check_bad '[supervisor]\noverspeed_rad_s = 1000\nmax_speed_rad_s = 900\n' 1 'supervisor.overspeed_rad_s (1000 rad/s) must be below supervisor.max_speed_rad_s (900 rad/s)'
check_bad '[supervisor]\noverspeed_rad_s = nan\n' 1 'supervisor.overspeed_rad_s'
check_bad '[controller.control]\nspeed_limit_rad_s = 480\n[supervisor]\noverspeed_rad_s = 471\n' 1 'controller.control.speed_limit_rad_s (480 rad/s) must be below supervisor.overspeed_rad_s (471 rad/s)'
check_bad '[controller.control]\nspeed_limit_rad_s = -1\n' 1 'control.speed_limit_rad_s'
check_bad '[controller.control]\nspeed_limit_rad_s = nan\n' 1 'control.speed_limit_rad_s'
check_bad '[controller.motor]\nrs_ohm = -1\n' 1 'controller.motor.rs_ohm'
check_bad '[gpio]\nchip = "gpiochip0"\n' 1 'gpio.chip and gpio.enable_line'
check_bad '[can]\ninterface = "can0"\ndata_bitrate_bit_s = 2000000\n' 1 'raise can.data_bitrate_bit_s'
check_bad 'this is not toml' 1 'bad.toml:1:'
# Every bad key at once, from the daemon's sections and the drive's.
check_bad '[can]\nnode = 22\nbitrate = 5\n[rt]\npriority = 100\n[controller.motor]\nrs_ohm = -1\n' 1 'controller.motor.rs_ohm'
out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
for want in 'bad.toml:2: can.node' 'bad.toml:3: can.bitrate: unknown key' 'bad.toml:5: rt.priority' 'bad.toml:7: controller.motor.rs_ohm'; do
  if [[ "$out" != *"$want"* ]]; then echo "FAIL: '$want' missing from the list of bad keys: $out"; fail=1; fi
done
# Every broken cross-key rule at once, the daemon's and the drive's.
check_bad '[supervisor]\ntrip_temp_C = 100\novercurrent_A = 5000\n[gpio]\nfault_line = 3\n' 1 'supervisor.trip_temp_C'
out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
for want in 'supervisor.overcurrent_A (5000 A) must be below' 'gpio.fault_line needs gpio.chip'; do
  if [[ "$out" != *"$want"* ]]; then echo "FAIL: '$want' missing from the broken rules: $out"; fail=1; fi
done
check_bad '[controller.derating]\nstart_C = 200\nlimit_C = 150\n[controller.injection]\nrecord_time_s = 0.01\nsettle_s = 0.5\n' 1 'derating.start_C must be below'
out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
if [[ "$out" != *'injection.record_time_s must be longer'* ]]; then
  echo "FAIL: the second broken drive rule is missing: $out"; fail=1
fi
if "$exe" --config "$dir/missing.toml" --check >/dev/null 2>&1; then
  echo "FAIL: a missing file passed"; fail=1
fi
check_bad '[controller.derating]\nmagnet_start_C = 160\n' 1 'derating.magnet_start_C must be below derating.magnet_limit_C'
# A bad command line is a configuration error (exit 2, which the unit does not restart on) and
# names the option; --help and --version exit 0.
for args in "--bogus" "--log-level loud --config $dir/bad.toml"; do
  # shellcheck disable=SC2086
  out=$("$exe" $args 2>&1)
  rc=$?
  want=${args%% *}
  if [ "$rc" -ne 2 ] || [[ "$out" != *"$want"* ]]; then
    echo "FAIL: '$args' should exit 2 naming $want, got exit $rc: $out"; fail=1
  else
    echo "ok (rejected): $args: $out"
  fi
done
for args in --help --version; do
  "$exe" "$args" >/dev/null 2>&1 || { echo "FAIL: $args did not exit 0"; fail=1; }
done
exit $fail
