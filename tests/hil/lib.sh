# Sourced by the HIL scripts that start processes (daemon_hil.sh, daemon_axes_hil.sh; scripts/demo-bus
# for hil_observer): how
# they fail, stop what they started, keep or remove their work directory, and wait for a
# process to say something. The script sets `prog` first.

pids=()  # every process started, stopped on exit
ok=0     # set to 1 just before PASS: the work directory is removed unless kept

# A prefix for the processes that watch the bus (candump, pmsm-thermal monitor): a higher
# priority where the script may set one (root in the User-Mode Linux guest). The guest has one
# CPU, and the lockstep pair, whose daemon sends and waits in one system call (io_uring), outran
# observers at its own priority: daemon_hil's candump lost a third of the heat-up's frames, the
# demo's kept 58 % of the samples. nice -10 rather than SCHED_FIFO: enough to keep up (every frame
# captured), without preempting the daemon at every frame (its step latency's median read
# < 32 us under nice, < 256-512 us under FIFO; the heat-up took 52-60 s of wall time either way).
hil_observer=()
if nice -n -10 true 2>/dev/null; then
  hil_observer=(nice -n -10)
fi

die() {
  echo "$prog: FAIL: $*" >&2
  exit 1
}

# hil_cleanup_on_exit WORK KEEP: on exit, pass or fail, TERM and reap every process in pids;
# remove WORK after a pass unless KEEP is 1, otherwise keep it and say where it is. Under
# User-Mode Linux the guest's /tmp is an overlay that vanishes with the guest, so a kept WORK
# is copied into the working directory (ctest's: build/<preset>/tests), which the host sees.
hil_cleanup_on_exit() {
  hil_work=$1
  hil_keep=$2
  trap hil_cleanup EXIT
}
hil_cleanup() {
  local pid
  for pid in "${pids[@]}"; do
    kill -TERM "$pid" 2>/dev/null || true
  done
  for pid in "${pids[@]}"; do
    wait "$pid" 2>/dev/null || true
  done
  if [ "$ok" = 1 ] && [ "$hil_keep" != 1 ]; then
    rm -rf "$hil_work"
  elif [ "${PMSM_VCAN_MODE:-}" = uml ] && cp -a "$hil_work" "$PWD/" 2>/dev/null; then
    echo "$prog: work directory kept: $PWD/$(basename "$hil_work") (copied out of the guest's /tmp)" >&2
  else
    echo "$prog: work directory kept: $hil_work" >&2
  fi
}

# hil_wait_for FILE PATTERN PID SECONDS WHAT: until FILE (PID's log) has a line matching
# PATTERN; fails at once if PID exits, and after SECONDS.
hil_wait_for() {
  local file=$1 pattern=$2 pid=$3 seconds=$4 what=$5 i
  for i in $(seq $((seconds * 10))); do
    grep -q -- "$pattern" "$file" 2>/dev/null && return 0
    kill -0 "$pid" 2>/dev/null || die "$what exited: $(tail -3 "$file")"
    sleep 0.1
  done
  die "$what did not say '$pattern' within $seconds s: $(tail -3 "$file")"
}
