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
check_bad '[can]\nnode = 4294967297\n' 1 'bad.toml:2: can.node: must be in [0, 15], got 4294967297'
check_bad '[can]\ninterfaec = "vcan0"\n' 1 'can.interfaec'
# A physical bus's load is enforced, and the 10 kHz loop's two fast frames do not fit CAN FD at
# 1/8 Mbit/s; a name this machine does not have is said to be missing too (a typo of vcan0).
check_bad '[can]\ninterface = "pmsmnosuch7"\n' 1 "can.interface 'pmsmnosuch7' is taken for a physical CAN bus with these bit rates"
check_bad '[can]\ninterface = "pmsmnosuch7"\n' 1 "this machine has no interface 'pmsmnosuch7' either (a name mistyped?)"
check_bad '[rt]\npriority = "high"\n' 1 'rt.priority'
# An interface this machine has that is no CAN interface is named as such beside the load's refusal.
check_bad '[can]\ninterface = "lo"\n' 1 "and 'lo' on this machine is not a CAN interface at all (its link type is 772, CAN's 280)"
# Under systemd's environment but with stderr on a pipe (a --check run from a service's shell),
# the refusal is printed where stderr goes, not sent to the journal: stderr is the journal's
# stream only when JOURNAL_STREAM names its device and inode.
printf '[can]\nnode = 16\n' > "$dir/bad.toml"
out=$(INVOCATION_ID=0123456789abcdef JOURNAL_STREAM=8:12345 "$exe" --config "$dir/bad.toml" --check 2>&1)
rc=$?
if [ "$rc" -ne 1 ] || [[ "$out" != *"can.node: must be in [0, 15], got 16"* ]]; then
  echo "FAIL: under a unit's environment with stderr on a pipe, --check said nothing (exit $rc): '$out'"; fail=1
fi
# An interface that exists and cannot be opened (not CAN; here, or without CAN in the kernel) is
# a configuration to fix: exit 2, which the unit does not restart. One that does not exist (yet)
# is waited for: exit 1, restarted.
printf '[can]\ninterface = "lo"\n[rt]\npriority = 0\nlock_memory = false\n[controller.control]\nperiod_s = 0.001\ncurrent_bandwidth_rad_s = 500\n' > "$dir/lo.toml"
rc=0
out=$(timeout 20 "$exe" --config "$dir/lo.toml" 2>&1) || rc=$?
if [ "$rc" -ne 2 ] || [[ "$out" != *"the interface exists: a configuration to fix, not retried"* ]]; then
  echo "FAIL: an existing non-CAN interface: exit $rc (expected 2): $out"; fail=1
fi
# At 1 kHz 'lo' fits the bus budget; --check refuses it all the same, as the start does.
out=$("$exe" --config "$dir/lo.toml" --check 2>&1); rc=$?
if [ "$rc" -ne 1 ] || [[ "$out" != *"can.interface 'lo' on this machine is not a CAN interface (its link type is 772, CAN's 280): the start would refuse it"* ]]; then
  echo "FAIL: --check passed a non-CAN interface the start refuses (exit $rc): $out"; fail=1
fi
# A virtual bus that is not there is named with the commands that make one (where the kernel
# has CAN: without, the message says what to load; daemon_hil runs this case in User-Mode Linux).
sed 's/"lo"/"vcan7"/' "$dir/lo.toml" > "$dir/vcan7.toml"
if ! ip link show vcan7 >/dev/null 2>&1; then
  rc=0
  out=$(timeout 20 "$exe" --config "$dir/vcan7.toml" 2>&1) || rc=$?
  if [[ "$out" == *"this kernel has no CAN support"* ]]; then
    want="load the can and can-raw modules"
  else
    want="(retried; a virtual bus is made by hand: ip link add vcan7 type vcan && ip link set vcan7 up)"
  fi
  if [ "$rc" -ne 1 ] || [[ "$out" != *"$want"* ]]; then
    echo "FAIL: a missing virtual bus: exit $rc (expected 1, and '$want'): $out"; fail=1
  fi
fi
sed 's/"lo"/"pmsmnosuch9"/' "$dir/lo.toml" > "$dir/nosuch.toml"
rc=0
out=$(timeout 20 "$exe" --config "$dir/nosuch.toml" 2>&1) || rc=$?
if [ "$rc" -ne 1 ]; then
  echo "FAIL: a missing interface: exit $rc (expected 1, restarted until it appears): $out"; fail=1
fi
# Outside what a calibration's T0 may be: a calibration on such an ambient stored a file the
# next start refused.
check_bad '[supervisor]\nambient_max_C = 250.0\n' 1 'bad.toml:2: supervisor.ambient_max_C: must be in [-50, 200], got 250'
# A NUL in the interface's name is no name (it read as "vcan0").
check_bad '[can]\ninterface = "vcan0\\u0000x"\n' 1 'can.interface: contains a control character (U+0000) at position 6'
check_bad '[supervisor]\ntrip_temp_C = 100\n' 1 'supervisor.trip_temp_C'
check_bad '[supervisor]\ndc_bus_min_V = 700\n' 1 'nominal_dc_bus_V'
check_bad '[supervisor]\noverspeed_rad_s = 1000\nmax_speed_rad_s = 900\n' 1 'bad.toml:2: supervisor.overspeed_rad_s (1000 rad/s) must be below supervisor.max_speed_rad_s (900 rad/s, '"$dir"'/bad.toml:3)'
check_bad '[supervisor]\noverspeed_rad_s = nan\n' 1 'supervisor.overspeed_rad_s'
check_bad '[controller.control]\nspeed_limit_rad_s = 480\n[supervisor]\noverspeed_rad_s = 471\n' 1 'bad.toml:2: controller.control.speed_limit_rad_s (480 rad/s) must be below supervisor.overspeed_rad_s (471 rad/s, '"$dir"'/bad.toml:4)'
# Where the file gives only the keys a default follows, the defaults say how they follow, and
# the message is located at that key.
check_bad '[controller.sensors]\ndc_bus_full_scale_V = 600\n' 1 'bad.toml:2: controller.control.nominal_dc_bus_V (650 V, its default) lies outside supervisor.dc_bus_min_V (390 V, its default: 0.6 x controller.control.nominal_dc_bus_V) .. supervisor.dc_bus_max_V (588 V, its default: the lower of'
check_bad '[controller.sensors]\ncurrent_range_A = 85\n' 1 'bad.toml:2: supervisor.overcurrent_A (76.5 A, its default: 90 % of controller.sensors.current_range_A) must be above controller.derating.max_current_A (80 A, its default)'

check_bad '[controller.motor]\nrated_speed_rad_s = 300\n[supervisor]\nmax_speed_rad_s = 400\n' 1 'bad.toml:4: supervisor.overspeed_rad_s (450 rad/s, its default: 1.5 x controller.motor.rated_speed_rad_s) must be below supervisor.max_speed_rad_s (400 rad/s)'
check_bad '[controller.control]\nspeed_limit_rad_s = -1\n' 1 'control.speed_limit_rad_s'
check_bad '[controller.control]\nspeed_limit_rad_s = nan\n' 1 'control.speed_limit_rad_s'
check_bad '[controller.motor]\nrs_ohm = -1\n' 1 'controller.motor.rs_ohm'
check_bad '[gpio]\nchip = "gpiochip0"\n' 1 'gpio.chip and gpio.enable_line'
check_bad '[can]\ninterface = "can0"\ndata_bitrate_bit_s = 2000000\n' 1 'bad.toml:2: the fast loop ('
# (Located at can.interface, which makes it a real bus; the cure named.)
[[ "$out" == *'raise can.data_bitrate_bit_s'* ]] || { echo "FAIL: the bus budget's refusal names no cure: $out"; fail=1; }
check_bad 'this is not toml' 1 'bad.toml:1:'
# The supervisor's section put under [controller]: named with where it belongs.
check_bad '[controller.supervisor]\ndc_bus_max_V = 760\n' 1 "bad.toml:1: controller.supervisor: the supervisor's keys are a section of their own at the file's top level, [supervisor]"
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
check_bad '[controller.derating]\nstart_C = 200\nlimit_C = 150\n[controller.injection]\nrecord_time_s = 0.01\nsettle_s = 0.5\n' 1 'controller.derating.start_C (200 C) must be below controller.derating.limit_C (150 C, '
out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
if [[ "$out" != *'controller.injection.record_time_s (0.01 s) must be longer than controller.injection.settle_s (0.5 s'* ]]; then
  echo "FAIL: the second broken drive rule is missing: $out"; fail=1
fi
if "$exe" --config "$dir/missing.toml" --check >/dev/null 2>&1; then
  echo "FAIL: a missing file passed"; fail=1
fi
check_bad '[controller.derating]\nmagnet_start_C = 160\n' 1 'derating.magnet_start_C (160 C) must be below controller.derating.magnet_limit_C (150 C, its default)'
# The daemon's own rules are reported alongside a broken drive rule (its values parsed).
check_bad '[supervisor]\nambient_min_C = 100.0\nambient_max_C = 0.0\n[controller.derating]\nstart_C = 160.0\nlimit_C = 150.0\n' 1 'derating.start_C (160 C) must be below'
out=$("$exe" --config "$dir/bad.toml" --check 2>&1)
if [[ "$out" != *'supervisor.ambient_min_C (100 C) must be below supervisor.ambient_max_C (0 C, '"$dir"'/bad.toml:3)'* ]]; then
  echo "FAIL: the daemon's rule is missing beside the drive's: $out"; fail=1
fi
# A section another parser reads, given as something else, is an error (not skipped with its keys).
check_bad 'controller = "x"\n' 1 'bad.toml:1: controller: expected a table (section [controller]), got a string'
check_bad '[[controller]]\nmotor = 1\n' 1 'controller: expected a table (section [controller]), got an array'
# Rules between the daemon's keys and the drive's.
check_bad '[can]\ninterface = ""\n' 1 'bad.toml:2: can.interface: an interface name is 1 to 15 characters, got an empty one'
check_bad '[can]\ninterface = "vcan0123456789abcdef"\n' 1 'can.interface: an interface name is 1 to 15 characters, got 20'
check_bad '[can]\ninterface = "can/0"\n' 1 "can.interface: an interface name has no '/', ':' or white space"
check_bad '[can]\nsample_timeout_ms = 0.05\n' 1 'bad.toml:2: can.sample_timeout_ms (0.05 ms) must be above the control period controller.control.period_s (0.0001 s, its default)'
check_bad '[publish]\nthermal_estimate_s = 1e-9\n' 1 'bad.toml:2: publish.thermal_estimate_s (1e-09 s) is shorter than the control period controller.control.period_s (0.0001 s, its default)'
check_bad '[supervisor]\novercurrent_A = 50\n' 1 'bad.toml:2: supervisor.overcurrent_A (50 A) must be above controller.derating.max_current_A (80 A, its default)'
# A rule between two keys is located at the first of them the file gives.
check_bad '[supervisor]\ntrip_temp_C = 100\n' 1 'bad.toml:2: supervisor.trip_temp_C (100 C) must be above controller.derating.limit_C (155 C, its default)'
check_bad '[supervisor]\ndc_bus_min_V = 900\n' 1 'bad.toml:2: supervisor.dc_bus_min_V (900 V) must be below supervisor.dc_bus_max_V'
check_bad '[supervisor]\ndc_bus_max_V = 5000\n' 1 'bad.toml:2: supervisor.dc_bus_max_V (5000 V) must be below controller.sensors.dc_bus_full_scale_V (1000 V, its default)'
check_bad '[controller.sensors]\ndc_bus_full_scale_V = 10\n' 1 'supervisor.dc_bus_min_V (390 V, its default: 0.6 x controller.control.nominal_dc_bus_V) must be below supervisor.dc_bus_max_V (9.8 V, its default: the lower of'
check_bad '[gpio]\nchip = "gpiochip0"\nenable_line = 17\nfault_line = 17\n' 1 'bad.toml:4: gpio.fault_line and gpio.enable_line are both line 17'
check_bad '[gpio]\nchip = ""\nenable_line = 17\n' 1 'bad.toml:3: gpio.chip and gpio.enable_line go together'
# Rules between the drive's own keys (the loops and the bridge).
check_bad '[controller.control]\nperiod_s = 1e-3\n' 1 'controller.control.current_bandwidth_rad_s (2000 rad/s, its default) times controller.control.period_s (0.001 s) is 2, above 0.5'
check_bad '[controller.control]\nspeed_bandwidth_rad_s = 1000\n' 1 'controller.control.speed_bandwidth_rad_s (1000 rad/s) must be at most a fifth of controller.control.current_bandwidth_rad_s (2000 rad/s, its default)'
check_bad '[controller.control]\ndead_time_s = 1e-5\n' 1 'gives the bridge a voltage error of 65 V, beyond the +-50 V controller.injection.vx_initial_V allows'
check_bad '[controller.control]\nperiod_s = 2e-5\ndead_time_s = 5e-6\ncurrent_bandwidth_rad_s = 2000\n' 1 'controller.control.dead_time_s (5e-06 s) must be below a quarter of controller.control.period_s (2e-05 s'
check_bad '[controller.control]\nnominal_dc_bus_V = 1e-300\n' 1 'bad.toml:2: controller.control.nominal_dc_bus_V: must be in [1, 10000], got 1e-300'
check_bad '[supervisor]\ncommand_timeout_s = 1e-5\n' 1 'bad.toml:2: supervisor.command_timeout_s (1e-05 s) must be above the control period controller.control.period_s (0.0001 s, its default), or 0 (off)'
# The filter's noise keys are bounded (1e200 passed, and the drive tripped within 0.06 s).
check_bad '[controller.thermal]\nwinding_process_std_C_per_sqrt_s = 1e200\n' 1 'bad.toml:2: controller.thermal.winding_process_std_C_per_sqrt_s: must be in [0, 100], got 1e+200'
check_bad '[controller.thermal]\niron_loss_k2_W_s2_rad2 = 1e6\n' 1 'bad.toml:2: controller.thermal.iron_loss_k2_W_s2_rad2: must be in [0, 1000], got 1e+06'
# A calibration path that cannot be looked at is no missing calibration (it could not be written).
ln -s loop "$dir/loop"
check_bad "[controller.calibration]\nfile = \"$dir/loop\"\n" 1 "$dir/loop: cannot be looked at (Too many levels of symbolic links)"
printf 'format = 1\nrs0_ohm = 0.2\nt0_C = 25.0\nke0_std_V_s_per_rad = 0.01\n' > "$dir/ke0-std-alone.toml"
check_bad "[controller.calibration]\nfile = \"$dir/ke0-std-alone.toml\"\n" 1 "ke0_std_V_s_per_rad without ke0_V_s_per_rad"
# A stored calibration of another motor: valid as a file, outside this drive's window.
printf 'format = 1\nrs0_ohm = 5.0\nt0_C = 25.0\n' > "$dir/other-motor.toml"
check_bad "[controller.calibration]\nfile = \"$dir/other-motor.toml\"\n" 1 'calibration file refused: '"$dir"'/other-motor.toml: rs0_ohm 5 ohm lies above the drive'"'"'s plausibility window (controller.injection.rs_max_ohm = 0.27 ohm)'
# A calibration another axis wrote (a configuration copied for a second axis, still naming the
# first one's file): refused, naming both axes; this axis's is taken.
printf 'format = 1\nrs0_ohm = 0.13\nt0_C = 25.0\ncan_interface = "vcan0"\ncan_node = 2\n' > "$dir/node2-cal.toml"
check_bad "[controller.calibration]\nfile = \"$dir/node2-cal.toml\"\n" 1 "calibration file refused: $dir/node2-cal.toml was written by the axis on vcan0 node 2, and this daemon is node 0 on vcan0 (does another axis's configuration name the same controller.calibration.file?)"
printf '[can]\nnode = 2\n[controller.calibration]\nfile = "%s"\n' "$dir/node2-cal.toml" > "$dir/node2.toml"
out=$("$exe" --config "$dir/node2.toml" --check 2>&1) ||
  { echo "FAIL: node 2's own calibration refused: $out"; fail=1; }
# A file that passes --check (exit 0) with a warning holding each of the texts given.
#   check_warns FILE_TEXT WANT...
check_warns() {
  local text=$1 want
  shift
  printf '%b' "$text" > "$dir/warns.toml"
  out=$("$exe" --config "$dir/warns.toml" --check 2>&1); rc=$?
  for want in "$@"; do
    if [ "$rc" -ne 0 ] || [[ "$out" != *"$want"* ]]; then
      echo "FAIL: --check should pass (exit 0) warning '$want', got exit $rc: $out"; fail=1
      return
    fi
  done
  echo "ok (warned): $out"
}
# A calibration or thermal-state file where nothing can be written: warned about (a drive may
# run on a read-only calibration), not found out when a calibration completes.
check_warns "[controller.calibration]\nfile = \"$dir/no-such-dir/cal.toml\"\n[controller.thermal]\nstate_file = \"$dir\"\n" \
  "controller.calibration.file = $dir/no-such-dir/cal.toml: its directory $dir/no-such-dir does not exist: nothing this run learns can be stored there" \
  "controller.thermal.state_file = $dir: it is a directory"
# A method that misleads on a machine configured as salient (app::configuration_warnings).
check_warns "[controller.injection]\nmax_torque_disturbance_Nm = 1.5\nseparation = \"unipolar\"\n" \
  'controller.injection: method = "fixed-magnitude", separation = "unipolar" on a machine configured as salient'
# A salient machine with torque-neutral pulses and no flux map (app::salient_flux_map_warning).
check_warns "[controller.motor]\nlq_H = 6.6e-3\n[controller.injection]\nmax_torque_disturbance_Nm = 1.5\n" \
  'controller.motor: a salient machine (injection.max_torque_disturbance_Nm = 1.5 N m) with torque-neutral pulses'
# A real-time priority the shipped unit cannot grant (its LimitRTPRIO=): warned, naming the limit.
limit=$(sed -n 's/^LimitRTPRIO=//p' "$src/systemd/pmsm-thermald@.service")
check_warns "[rt]\npriority = $((limit + 1))\n" "rt.priority = $((limit + 1)) is above pmsm-thermald@.service's LimitRTPRIO=$limit"
printf '[rt]\npriority = %s\n' "$limit" > "$dir/rt-limit.toml"
out=$("$exe" --config "$dir/rt-limit.toml" --check 2>&1)
[[ "$out" != *"LimitRTPRIO"* ]] || { echo "FAIL: rt.priority = $limit, the unit's limit, warned: $out"; fail=1; }
# A thermal state file the start would not use (a NaN): --check says so, as the start does,
# and passes (the daemon starts from the ambient sensor without it); a usable one is named.
now=$(date +%s)
printf '# pmsm-thermal thermal state\nformat = 1\nwinding_C = nan\nhousing_C = 60.0\nwinding_std_C = 2.0\nambient_C = 25.0\nsaved_unix_s = %s\n' "$now" > "$dir/state-nan.toml"
check_warns "[controller.thermal]\nstate_file = \"$dir/state-nan.toml\"\n" \
  "thermal state not usable: $dir/state-nan.toml:3: winding_C: nan is out of range" "; thermal state not usable)"
printf '# pmsm-thermal thermal state\nformat = 1\nwinding_C = 71.5\nhousing_C = 60.0\nwinding_std_C = 2.0\nambient_C = 25.0\nsaved_unix_s = %s\n' "$now" > "$dir/state-ok.toml"
check_warns "[controller.thermal]\nstate_file = \"$dir/state-ok.toml\"\n" "; thermal state usable (winding 71.5 C, saved "
# No thermal state configured: the OK line says which item that is.
check_warns "[can]\nnode = 3\n" "; calibration not configured; thermal state not configured)"
# A learned block the start would drop (half a loss block, half a cooling pair): said, the
# temperatures usable.
{ cat "$dir/state-ok.toml"; printf 'missing_loss_W = 3.0\ncooling_scale_error = 0.1\n'; } > "$dir/state-halves.toml"
check_warns "[controller.thermal]\nstate_file = \"$dir/state-halves.toml\"\n" \
  "thermal state: the loss model's errors would not be used ($dir/state-halves.toml: missing_loss_std_W is missing" \
  "thermal state: the cooling path's error would not be used ($dir/state-halves.toml: cooling_scale_std is missing" \
  "; thermal state usable (winding 71.5 C, saved "
# One another axis wrote (a configuration copied for a second axis, its state file left as the
# first one's) is not this axis's winding; the axis that wrote it, when it is this one, is.
{ cat "$dir/state-ok.toml"; printf 'can_interface = "vcan0"\ncan_node = 2\n'; } > "$dir/state-node2.toml"
check_warns "[controller.thermal]\nstate_file = \"$dir/state-node2.toml\"\n" \
  "thermal state not usable: $dir/state-node2.toml was written by the axis on vcan0 node 2, and this daemon is node 0 on vcan0 (does another axis's configuration name the same controller.thermal.state_file?)" \
  "; thermal state not usable)"
check_warns "[can]\nnode = 2\n[controller.thermal]\nstate_file = \"$dir/state-node2.toml\"\n" "; thermal state usable (winding 71.5 C, saved "
# One without the drive's header (written by hand, another file that parses) is not restored, as
# it is not written over.
tail -n +2 "$dir/state-ok.toml" > "$dir/state-headless.toml"
check_warns "[controller.thermal]\nstate_file = \"$dir/state-headless.toml\"\n" \
  "is no thermal state file (it starts \"format = 1\", not \"# pmsm-thermal thermal state\"): not used" "; thermal state not usable)"
# A stored Ke0 far off the motor's EMF constant (another motor's, other units, or a
# motor.ke_V_s_per_rad entered wrong, which a drive's own measurement would show): warned, naming both.
printf 'format = 1\nrs0_ohm = 0.2\nt0_C = 25.0\nke0_V_s_per_rad = 100.0\n' > "$dir/other-ke0.toml"
check_warns "[controller.calibration]\nfile = \"$dir/other-ke0.toml\"\n" \
  "calibration: Ke0 100 V s/rad (phase peak per mechanical rad/s) is +10192 % off motor.ke_V_s_per_rad's 0.971631 V s/rad in that form"
# A drive whose current limit the bus's DRIVE_STATUS cannot carry (0..400 A): warned, naming both.
check_warns '[controller.derating]\nmax_current_A = 600\n[controller.sensors]\ncurrent_range_A = 1000\n[supervisor]\novercurrent_A = 800\n' \
  "controller.derating.max_current_A (600 A) lies beyond DRIVE_STATUS CurrentLimit's range (up to 400 A): while the limit is above it, the frame reads 400 A"
# Another motor on the reference machine's thermal model and derating floor: warned, not refused.
check_warns '[controller.motor]\ncontinuous_current_A_rms = 4.5\n[controller.sensors]\ncurrent_range_A = 25.0\n[controller.derating]\nmax_current_A = 19.0\n' \
  "controller.thermal: the thermal model has the reference machine's values (11.9 kW" \
  "controller.derating.min_current_A = 10 A lies above the motor's rated peak current (6.36 A"
# A rated speed the bus cannot hold without field weakening (Table I's EMF at 650 V: 367 rad/s).
check_warns '[controller.motor]\nrated_speed_rad_s = 400.0\n[controller.control]\nspeed_limit_rad_s = 450.0\n' \
  "controller.motor.rated_speed_rad_s = 400 rad/s lies beyond the 367 rad/s where the EMF"
# A speed loop whose gain turns the encoder's rounding into torque noise (Table I's motor on a
# 2 kg m^2 flywheel: 12 % of its rated torque at the default 60 rad/s): warned, naming the figures.
check_warns '[controller.motor]\ninertia_kg_m2 = 2.0\n' \
  "controller.control.speed_bandwidth_rad_s = 60 rad/s: the speed loop's gain (motor.inertia_kg_m2 = 2 kg m^2 x the bandwidth) turns the 14-bit encoder's rounding"
# check_clean NAME TOML WHAT: the configuration passes --check without a warning.
check_clean() {
  printf "$2" > "$dir/$1.toml"
  out=$("$exe" --config "$dir/$1.toml" --check 2>&1); rc=$?
  if [ "$rc" -ne 0 ] || [[ "$out" == *"warning"* ]]; then
    echo "FAIL: $3 should pass without a warning, got exit $rc: $out"; fail=1
  else
    echo "ok: $out"
  fi
}
# With field weakening on, the same rated speed is reachable: no warning.
check_clean field-weakening '[controller.motor]\nrated_speed_rad_s = 400.0\n[controller.control]\nspeed_limit_rad_s = 450.0\nfield_weakening = true\n' \
  "a rated speed beyond the EMF speed with field weakening on"
# Its own thermal model and floor: no warning.
check_clean small-motor-own '[controller.motor]\ncontinuous_current_A_rms = 4.5\n[controller.sensors]\ncurrent_range_A = 25.0\n[controller.derating]\nmax_current_A = 19.0\nmin_current_A = 3.0\n[controller.thermal]\nwinding_capacity_J_K = 330.0\n' \
  "a small motor with its own thermal model and floor"
# A bad command line is a configuration error (exit 2, which the unit does not restart on) and
# names the option; --help and --version exit 0.
# (--check with --keys printed the keys and answered 0 without validating anything.)
for args in "--bogus" "--log-level loud --config $dir/bad.toml" "--check --keys --config $dir/bad.toml"; do
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
# An empty --config is named as one, not as a missing flag.
out=$("$exe" --config "" --check 2>&1)
rc=$?
if [ "$rc" -ne 2 ] || [[ "$out" != *"--config: expected a file name, got an empty one"* ]]; then
  echo "FAIL: --config '' should exit 2 saying the name is empty, got exit $rc: $out"; fail=1
else
  echo "ok (rejected): --config '': $out"
fi
# Output that did not reach standard output (a full disk) is no success: --keys exits 1 (I/O).
out=$("$exe" --keys 2>&1 >/dev/full)
rc=$?
if [ "$rc" -ne 1 ] || [[ "$out" != *"pmsm-thermald: cannot write standard output (No space left on device)"* ]]; then
  echo "FAIL: --keys > /dev/full should exit 1 saying so, with the write's reason, got exit $rc: $out"; fail=1
else
  echo "ok (rejected): --keys > /dev/full: $out"
fi
for args in --help --version; do
  "$exe" "$args" >/dev/null 2>&1 || { echo "FAIL: $args did not exit 0"; fail=1; }
  # ... and to a full disk, 1 (I/O), saying so, as --keys.
  out=$("$exe" "$args" 2>&1 >/dev/full)
  rc=$?
  if [ "$rc" -ne 1 ] || [[ "$out" != *"pmsm-thermald: cannot write standard output ("* ]]; then
    echo "FAIL: $args > /dev/full should exit 1 saying so, got exit $rc: $out"; fail=1
  else
    echo "ok (rejected): $args > /dev/full: $out"
  fi
done
exit $fail
