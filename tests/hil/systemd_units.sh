#!/usr/bin/env bash
# systemd_units.sh BUILD_DIR: the shipped systemd units proven under a real systemd.
#
# The host's systemd boots as PID 1 inside User-Mode Linux (DESIGN §8), on a copy-on-write
# overlay of the host's root (the host's / is mounted read-only; every change lives in guest
# memory). Into the overlay go the project exactly as `cmake --install BUILD --prefix /usr`
# lays it out (units, networkd files, modules-load.d, sysusers.d, binaries, DBC, example
# configuration), then the test's configuration in /etc/pmsm-thermal (what a deployer edits)
# and a checking unit. Nothing of the shipped units is changed. The checking unit, inside
# the guest, proves:
#
#   1. systemd-modules-load loads can, can_raw, vcan (modules-load.d/pmsm-thermal.conf) and
#      systemd-networkd creates vcan0 with MTU 72 and brings it up (80-vcan0.netdev/.network);
#   2. systemd-sysusers created the pmsm-thermal user (sysusers.d/pmsm-thermal.conf);
#   3. `systemctl start pmsm-thermald@axis1.service` returns with the unit active: the daemon
#      sent READY=1 (Type=notify), running as pmsm-thermal with the unit's hardening;
#   4. the journal says the control thread got SCHED_FIFO and the memory was locked: the
#      hardening options do not stop the real-time set-up;
#   5. with pmsm-plant@axis1.service (lockstep: UML cannot run 10 kHz in real time) and a
#      supervisor's DRIVE_COMMAND stream, THERMAL_ESTIMATE frames of node 1 with Valid=1 appear
#      on vcan0, captured by candump inside the guest and decoded with the DBC;
#   6. the daemon stalled with SIGSTOP: the watchdog (WatchdogSec=2s) kills it, and
#      Restart=on-failure brings it back (NRestarts >= 1, a new main PID, active again), and
#      valid estimates flow again;
#   7. `systemctl stop` of both units ends them cleanly (Result=success);
#   8. `systemd-analyze security pmsm-thermald@axis1.service` is recorded.
#
# The guest powers itself off either way (SuccessAction=/FailureAction=); the host prints the
# checking log, keeps the journal and the capture on failure, and exits 0 (PASS), 1 (FAIL) or
# 77 (SKIP: what is missing is named). Runs the same on any Linux host: it needs no CAN in the
# host kernel, only user-mode-linux, busybox-static, udev and the host's systemd.
#
# Environment: SYSTEMD_UNITS_TIMEOUT (seconds for the whole guest, default 420),
# SYSTEMD_UNITS_KEEP=1 keeps the work directory (kept anyway on failure).
set -euo pipefail

prog=systemd_units
die() {
  echo "$prog: FAIL: $*" >&2
  exit 1
}
skip() {
  echo "$prog: SKIP: $*" >&2
  exit 77
}
[ $# -ge 1 ] || { echo "usage: $0 BUILD_DIR" >&2; exit 2; }
build=$(cd "$1" && pwd) || die "no build directory '$1'"
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
timeout_s=${SYSTEMD_UNITS_TIMEOUT:-420}

linux_bin=$(command -v linux.uml 2>/dev/null || echo /usr/bin/linux.uml)
[ -x "$linux_bin" ] || skip "linux.uml is missing (apt-get install user-mode-linux)"
command -v busybox >/dev/null || skip "busybox is missing (apt-get install busybox-static)"
[ -x /usr/sbin/switch_root ] || [ -x /sbin/switch_root ] || skip "switch_root is missing (apt-get install util-linux)"
[ -x /lib/systemd/systemd ] || skip "the host has no systemd to boot (apt-get install systemd)"
[ -x /lib/systemd/systemd-udevd ] || skip "systemd-udevd is missing (apt-get install udev): without udev networkd leaves vcan0 pending"
[ -x /lib/systemd/systemd-networkd ] || skip "systemd-networkd is missing (apt-get install systemd)"
uml_modules=(/usr/lib/uml/modules/*)
[ -e "${uml_modules[0]}/kernel/fs/overlayfs/overlay.ko" ] || skip "the UML kernel's modules are missing under /usr/lib/uml/modules"
[ ${#uml_modules[@]} -eq 1 ] || die "more than one UML kernel under /usr/lib/uml/modules: ${uml_modules[*]}"
uml_release=$(basename "${uml_modules[0]}")
for b in daemon/pmsm-thermald plant-emulator/pmsm-plant tools/pmsm-thermal; do
  [ -x "$build/$b" ] || die "missing executable $build/$b (build the project first)"
done

work=$(mktemp -d "${TMPDIR:-/tmp}/systemd-units.XXXXXXXX")
case "$work" in *,* | *[[:space:]]*) die "the work directory '$work' has a comma or a space (hostfs options cannot carry it)" ;; esac
ok=0
guest_pid=
cleanup() {
  if [ -n "$guest_pid" ]; then kill -TERM "$guest_pid" 2>/dev/null || true; fi
  if [ "$ok" = 1 ] && [ "${SYSTEMD_UNITS_KEEP:-0}" != 1 ]; then
    rm -rf "$work"
  else
    echo "$prog: work directory kept: $work (results/: check.log, journal.txt, candump.log)" >&2
  fi
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# The project as a package would lay it out.
DESTDIR="$work/stage" cmake --install "$build" --prefix /usr >"$work/install.log" 2>&1 ||
  die "cmake --install failed: $(tail -3 "$work/install.log")"
for f in usr/lib/systemd/system/pmsm-thermald@.service usr/lib/systemd/system/pmsm-plant@.service \
  usr/lib/systemd/network/80-vcan0.netdev usr/lib/systemd/network/80-vcan0.network \
  usr/lib/modules-load.d/pmsm-thermal.conf usr/lib/sysusers.d/pmsm-thermal.conf \
  usr/sbin/pmsm-thermald usr/bin/pmsm-plant usr/bin/pmsm-thermal usr/share/pmsm-thermal/pmsm-thermal.dbc \
  etc/pmsm-thermal/axis1.toml etc/pmsm-thermal/plant-axis1.toml etc/pmsm-thermal/plant-axis1.env; do
  [ -e "$work/stage/$f" ] || die "the install did not provide /$f"
done
# Debian 12 merges /usr: /lib is /usr/lib on the guest's root too.
# What a deployer edits: the axis's configuration, and the bench plant's arguments.
install -m 0644 "$src/tests/hil/data/systemd-axis1.toml" "$work/stage/etc/pmsm-thermal/axis1.toml"
install -m 0644 "$src/tests/hil/data/hil-plant.toml" "$work/stage/etc/pmsm-thermal/plant-axis1.toml"
echo 'PMSM_PLANT_ARGS=--node 1 --iface vcan0 --mode lockstep' >"$work/stage/etc/pmsm-thermal/plant-axis1.env"

results=$work/results
mkdir -p "$results" "$work/units" "$work/uml" "$work/mem"
printf -v q_results '%q' "$results"

# The checking unit and the target the guest boots into.
cat >"$work/units/pmsm-hil.target" <<'EOF'
[Unit]
Description=pmsm-thermal systemd HIL test
Requires=basic.target
After=basic.target
Wants=systemd-networkd.service pmsm-hil-check.service
AllowIsolate=yes
EOF
cat >"$work/units/pmsm-hil-check.service" <<EOF
[Unit]
Description=pmsm-thermal systemd HIL test: the checks
After=basic.target systemd-networkd.service systemd-sysusers.service systemd-modules-load.service
SuccessAction=poweroff
FailureAction=poweroff

[Service]
Type=exec
ExecStart=/bin/bash $work/check.sh
TimeoutStartSec=infinity
RuntimeMaxSec=$((timeout_s - 60))
StandardOutput=journal+console
StandardError=journal+console
EOF

cat >"$work/check.sh" <<EOF
#!/bin/bash
# Generated by $prog: runs inside the guest, as a systemd service.
set -u
export PATH=/usr/sbin:/usr/bin:/sbin:/bin
results=$q_results
unit=pmsm-thermald@axis1.service
plant=pmsm-plant@axis1.service
EOF
cat >>"$work/check.sh" <<'EOF'
log() { echo "$*" >>"$results/check.log"; }
collect() {
  systemctl --no-pager status "$unit" "$plant" >"$results/units.txt" 2>&1
  networkctl --no-pager status vcan0 >"$results/networkctl.txt" 2>&1
  journalctl -b --no-pager -o short-monotonic >"$results/journal.txt" 2>&1
  sync
}
fail() {
  log "FAIL: $*"
  collect
  echo 1 >"$results/status"
  sync
  exit 1
}
prop() { systemctl show -p "$2" --value "$1"; }
# Node 1's calibrated, valid estimates in the capture after line FROM, with the plant's truth
# beside them (pmsm-thermal monitor: the project's codec knows every node's IDs).
monitor_after() {  # FROM MIN_ESTIMATES
  tail -n +"$1" "$results/candump.log" |
    pmsm-thermal monitor --log - --node 1 --plain --threshold -100 --min-estimates "$2" >"$results/monitor.txt" 2>&1
}
wait_estimates() {  # FROM COUNT SECONDS
  local i
  for i in $(seq "$3"); do
    monitor_after "$1" "$2" && return 0
    sleep 1
  done
  return 1
}
summary() { grep -m1 'estimate vs truth' "$results/monitor.txt" | sed 's/^node  1  //'; }

log "systemd $(systemctl --version | head -1 | cut -d' ' -f2) is PID 1: $(cat /proc/1/comm); system state $(systemctl is-system-running)"

# 1. modules-load.d and systemd-networkd: vcan0, MTU 72, up.
for i in $(seq 30); do
  [ -d /sys/class/net/vcan0 ] && [ "$(cat /sys/class/net/vcan0/operstate)" != down ] && break
  sleep 1
done
[ -d /sys/class/net/vcan0 ] || fail "systemd-networkd did not create vcan0 from 80-vcan0.netdev ($(networkctl --no-pager list 2>&1 | tr '\n' ' '))"
mtu=$(cat /sys/class/net/vcan0/mtu)
flags=$(cat /sys/class/net/vcan0/flags)
[ "$mtu" = 72 ] || fail "vcan0 has MTU $mtu, not 72 (CAN FD)"
(( (flags & 1) != 0 )) || fail "vcan0 is not up (flags $flags)"
lsmod_line=$(grep -E '^(vcan|can_raw|can) ' /proc/modules | cut -d' ' -f1 | sort | tr '\n' ' ')
log "vcan0: created by systemd-networkd, MTU $mtu, up; modules loaded: $lsmod_line; networkctl: $(networkctl --no-pager list vcan0 2>/dev/null | sed -n 2p | tr -s ' ')"

# 2. sysusers.d
id pmsm-thermal >/dev/null 2>&1 || fail "systemd-sysusers did not create the pmsm-thermal user"
log "user: $(id pmsm-thermal)"

# The user-facing frames only (not the 10 kHz fast loop 0x010/0x020 + node): a small capture.
candump -L -r 16777216 vcan0,010~7F0,020~7F0,j >"$results/candump.log" 2>"$results/candump.err" &
candump_pid=$!

# 3. Type=notify: start returns once READY=1 arrived.
timeout 60 systemctl start "$unit" || fail "systemctl start $unit failed: $(systemctl --no-pager status "$unit" 2>&1 | tail -5 | tr '\n' ' ')"
[ "$(prop "$unit" ActiveState)" = active ] || fail "$unit is $(prop "$unit" ActiveState) after start"
[ "$(prop "$unit" Type)" = notify ] || fail "$unit is not Type=notify"
pid1=$(prop "$unit" MainPID)
user=$(ps -o user= -p "$pid1" | tr -d ' ')
[ "$user" = pmsm-thermal ] || fail "the daemon runs as '$user', not pmsm-thermal"
log "$unit: active (Type=notify, READY=1 received), main PID $pid1, user $user, status '$(prop "$unit" StatusText)'"

# 4. Real time under the unit's hardening.
sleep 1
journal=$(journalctl -b -u "$unit" -o cat --no-pager)
fifo=$(grep -m1 'SCHED_FIFO priority .* granted' <<<"$journal") || fail "the journal does not say SCHED_FIFO was granted: $(grep -iE 'sched|priority|real-time|rt ' <<<"$journal" | head -3 | tr '\n' ' ')"
locked=$(grep -m1 'memory locked' <<<"$journal") || fail "the journal does not say the memory was locked"
log "journal: '$fifo'; '$locked'"
# The unit's system-call filter (@system-service, which holds @aio) leaves the daemon io_uring:
# each period's answer and wait in one system call (docs/daemon.md, can.io_uring).
one_call=$(grep -m1 'CAN: each period' <<<"$journal") || fail "the journal does not say how the daemon sends and waits"
grep -q 'in one system call (io_uring)' <<<"$one_call" || fail "under the unit's hardening the daemon has no io_uring: '$one_call'"
log "journal: '$one_call'"
policy=$(ps -L -o cls=,rtprio=,comm= -p "$pid1" | awk '$1 == "FF" { print $3 " FF " $2; exit }')
[ -n "$policy" ] || fail "no thread of the daemon runs SCHED_FIFO: $(ps -L -o cls=,rtprio=,comm= -p "$pid1" | tr '\n' ';')"
log "thread with SCHED_FIFO: $policy"

# 5. The plant, a supervisor's commands, estimates on the bus.
pmsm-thermal command --iface vcan0 --node 1 --mode speed --speed 94 --calibrate-at 25 --period-ms 100 \
  >"$results/command.log" 2>&1 &
timeout 30 systemctl start "$plant" || fail "systemctl start $plant failed"
[ "$(prop "$plant" ActiveState)" = active ] || fail "$plant is $(prop "$plant" ActiveState)"
log "$plant: active, main PID $(prop "$plant" MainPID)"
wait_estimates 1 5 150 || fail "fewer than 5 calibrated THERMAL_ESTIMATE frames of node 1 on vcan0 after 150 s: $(tail -2 "$results/monitor.txt" | tr '\n' ' ')"
log "bus (candump in the guest, decoded): $(summary)"

# 6. Watchdog: stall the whole process; the watchdog must kill it and the unit restart it.
restarts0=$(prop "$unit" NRestarts)
kill -STOP "$pid1"
log "SIGSTOP to the daemon (PID $pid1) at $(date +%T)"
for i in $(seq 40); do
  pid2=$(prop "$unit" MainPID)
  [ "$(prop "$unit" NRestarts)" -gt "$restarts0" ] && [ "$(prop "$unit" ActiveState)" = active ] && [ "$pid2" != "$pid1" ] && [ "$pid2" != 0 ] && break
  sleep 0.5
done
restarts=$(prop "$unit" NRestarts)
[ "$restarts" -gt "$restarts0" ] || fail "the stalled daemon was not restarted (NRestarts $restarts, state $(prop "$unit" ActiveState)/$(prop "$unit" SubState))"
[ "$(prop "$unit" ActiveState)" = active ] || fail "after the watchdog, $unit is $(prop "$unit" ActiveState)"
wd=$(journalctl -b -u "$unit" -o cat --no-pager | grep -m1 -i 'watchdog timeout') || fail "the journal has no watchdog timeout for $unit"
log "watchdog: '$wd'; NRestarts $restarts; new main PID $pid2 at $(date +%T)"
mark=$(wc -l <"$results/candump.log")
wait_estimates "$mark" 3 120 || fail "fewer than 3 calibrated estimates in 120 s after the watchdog restart: $(tail -2 "$results/monitor.txt" | tr '\n' ' ')"
log "after the restart: $(summary)"
restored=$(journalctl -b -u "$unit" -o cat --no-pager | grep -E 'calibration|thermal state' | tail -2 | tr '\n' ';')
log "restarted daemon's start-up: $restored"

# 7. Clean stop.
systemctl stop "$plant" "$unit"
for u in "$unit" "$plant"; do
  r=$(prop "$u" Result)
  [ "$r" = success ] || fail "$u stopped with Result=$r"
done
log "stop: both units inactive, Result=success"
kill "$candump_pid" 2>/dev/null

# 8. The unit's exposure as systemd rates it.
systemd-analyze security --no-pager "$unit" >"$results/security.txt" 2>&1
log "systemd-analyze security: $(tail -1 "$results/security.txt")"

collect
echo 0 >"$results/status"
log "PASS"
sync
exit 0
EOF

# Stage 1, the guest's first PID 1: the read-only host root under a tmpfs overlay, the work
# directory writable, the project installed into the overlay, then systemd.
printf -v q_work '%q' "$work"
cat >"$work/init" <<EOF
#!/bin/bash
export PATH=/usr/sbin:/usr/bin:/sbin:/bin
work=$q_work
release=$uml_release
EOF
cat >>"$work/init" <<'EOF'
fail() {
  echo "stage 1: $*" >"$work/stage1.err" 2>/dev/null || echo "stage 1: $*"
  busybox poweroff -f
}
mount -n -t proc proc /proc || fail "cannot mount /proc"
modules=/usr/lib/uml/modules/$release/kernel
busybox insmod "$modules/fs/overlayfs/overlay.ko" || fail "cannot load overlay.ko"
busybox insmod "$modules/fs/autofs/autofs4.ko" 2>/dev/null || true
mount -n -t tmpfs -o mode=0755 cow /mnt || fail "cannot mount a tmpfs on /mnt"
mkdir -p /mnt/upper /mnt/work /mnt/root
mount -n -t overlay overlay -o lowerdir=/,upperdir=/mnt/upper,workdir=/mnt/work /mnt/root ||
  fail "cannot mount the overlay"
# A fresh machine's /tmp, not the host's: at boot systemd-tmpfiles empties /tmp, and through
# the overlay every file of a busy host /tmp would cost the guest's tmpfs a whiteout (a host
# /tmp of a few hundred thousand files filled it: "No space left on device" for the units).
mount -n -t tmpfs -o mode=1777 tmp /mnt/root/tmp || fail "cannot mount a tmpfs on /tmp"
mkdir -p "/mnt/root$work"
mount -n -t hostfs -o "$work" hostfs "/mnt/root$work" || fail "cannot mount $work writable"
# The host is a container: systemd would believe it runs in one and ignore systemd.unit=.
rm -f /mnt/root/.dockerenv /mnt/root/run/.containerenv
cp -a "$work/stage/." /mnt/root/ || fail "cannot install the project into the overlay"
cp "$work/units/"* /mnt/root/etc/systemd/system/ || fail "cannot install the checking units"
mkdir -p /mnt/root/usr/lib/modules
ln -sfn "/usr/lib/uml/modules/$release" "/mnt/root/usr/lib/modules/$release"
# A fresh machine: systemd creates its machine-id in the overlay.
: >/mnt/root/etc/machine-id
if mountpoint -q /dev; then mount -n --move /dev /mnt/root/dev || fail "cannot move /dev"; fi
mount -n --move /proc /mnt/root/proc || fail "cannot move /proc"
exec switch_root /mnt/root /lib/systemd/systemd
EOF
chmod 0755 "$work/init" "$work/check.sh"

echo "$prog: booting systemd in User-Mode Linux ($uml_release), work $work"
t0=$(date +%s)
set +e
TMPDIR="$work/mem" timeout --kill-after=10 "$timeout_s" "$src/scripts/uml-run" "$work" "$linux_bin" mem=384M "umid=systemd-units-$$" \
  "uml_dir=$work/uml" rootfstype=hostfs rootflags=/ ro quiet "init=$work/init" con=null "con0=fd:0,fd:1" \
  systemd.unit=pmsm-hil.target systemd.mask=systemd-timesyncd.service systemd.show_status=0 \
  </dev/null > >(cat >"$work/console") 2>&1 &
guest_pid=$!
wait "$guest_pid"
uml_rc=$?
guest_pid=
set -e
t1=$(date +%s)

[ -f "$results/check.log" ] && sed "s/^/$prog: guest: /" "$results/check.log"
if [ -s "$results/security.txt" ]; then
  echo "$prog: systemd-analyze security pmsm-thermald@axis1.service (inside the guest):"
  sed 's/^/  /' "$results/security.txt" | tail -n 3
fi
if [ -s "$work/stage1.err" ]; then
  die "the guest could not start systemd: $(cat "$work/stage1.err")"
fi
if [ ! -f "$results/status" ]; then
  tail -n 30 "$work/console" >&2 || true
  # As scripts/vcan-env: the host's CPU kept this UML kernel from running any process.
  if reason=$("$src/scripts/uml-run" --host-incompatible "$work/console"); then
    skip "$reason; the check did not run"
  fi
  if [ "$uml_rc" -eq 124 ] || [ "$uml_rc" -eq 137 ]; then
    die "the guest did not finish within $timeout_s s (SYSTEMD_UNITS_TIMEOUT)"
  fi
  die "the guest stopped (exit $uml_rc) without a result (console above)"
fi
[ "$(cat "$results/status")" = 0 ] || die "a check failed inside the guest (journal: $results/journal.txt)"
ok=1
echo "$prog: PASS (guest boot, checks and power-off in $((t1 - t0)) s)"
