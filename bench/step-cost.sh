#!/usr/bin/env bash
# step-cost.sh BUILD_DIR [--scenario FILE] [--seconds S] [--function controller|node] [--budget N]
#
# Instructions per control step, by step class, counted by callgrind: a deterministic figure
# (the same on any x86-64 machine with the same build), unlike a time on a shared machine.
# pmsm_step_cost replays the scenario's closed loop and dumps callgrind's counters after every
# step; callgrind collects only inside the chosen function:
#   controller  pmsm::core::DriveController::step (the control law, the injection scheduler,
#               the estimator, the thermal filter)
#   node        pmsm::app::DriveNode::step (the daemon's whole per-sample path: sensor front
#               end, supervisor, the controller, the period's publications)
# Prints, per class (see bench/step_cost.cpp), the steps, the mean and the largest count with
# the step it happened at, then the worst step of all. With --budget N, exits 1 when any step
# costs more than N instructions (ctest step_cost_budget; docs/performance.md).
#
# Exit status: 0, 1 (over budget), 2 (bad usage), 77 (valgrind missing: skipped).
set -euo pipefail

usage() { sed -n '2,2p' "$0" | sed 's/^# //' >&2; exit 2; }
[ $# -ge 1 ] || usage
build=$1
shift
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
scenario=$src/bench/scenarios/step-cost.toml
seconds=4
function=controller
budget=
while [ $# -gt 0 ]; do
  case "$1" in
    --scenario) scenario=$2; shift 2 ;;
    --seconds) seconds=$2; shift 2 ;;
    --function) function=$2; shift 2 ;;
    --budget) budget=$2; shift 2 ;;
    *) echo "step-cost: unknown option '$1'" >&2; usage ;;
  esac
done
# The argument list's '(' is part of the pattern: callgrind toggles collection on entering and on
# leaving every function that matches, so a function the step calls whose name also began with
# "step" (step_without_sample) would turn collection off inside it. (So would a partial-inlining
# clone, `step(...) [clone .part.N]`, that step called: none in GCC 12's builds of this code,
# `nm -C BUILD/bench/pmsm_step_cost | grep 'DriveController::step('` lists one symbol.)
case "$function" in
  controller) pattern='pmsm::core::DriveController::step(*' ;;
  node) pattern='pmsm::app::DriveNode::step(*' ;;
  *) echo "step-cost: --function must be controller or node, not '$function'" >&2; exit 2 ;;
esac
if [ -n "$budget" ] && ! [[ "$budget" =~ ^[0-9]+$ ]]; then
  echo "step-cost: --budget must be a number of instructions, not '$budget'" >&2
  exit 2
fi
exe=$build/bench/pmsm_step_cost
[ -x "$exe" ] || { echo "step-cost: missing $exe (build the project first)" >&2; exit 2; }
[ -f "$scenario" ] || { echo "step-cost: no scenario file '$scenario'" >&2; exit 2; }
if ! command -v valgrind >/dev/null; then
  echo "step-cost: SKIP: valgrind is missing (apt-get install valgrind)" >&2
  exit 77
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/step-cost.XXXXXXXX")
trap 'rm -rf "$work"' EXIT
# One dump per step (about 10 kB each), all in one file; only the summaries are read.
valgrind --tool=callgrind --collect-atstart=no "--toggle-collect=$pattern" --combine-dumps=yes \
  --dump-instr=no --dump-line=no "--callgrind-out-file=$work/callgrind.out" \
  "$exe" "$scenario" "$seconds" >"$work/stdout" 2>"$work/valgrind.log" || {
  echo "step-cost: the replay failed under valgrind:" >&2
  tail -5 "$work/valgrind.log" >&2
  exit 2
}
echo "step-cost: $(cat "$work/stdout")"
echo "step-cost: instructions per step in $pattern (callgrind, $(basename "$build") build)"
awk -v budget="$budget" '
  /^desc: Trigger: Client Request: step / { k = $6; c = $7; labelled = 1 }
  /^summary: / && labelled {
    labelled = 0
    n[c]++; sum[c] += $2
    if ($2 > max[c]) { max[c] = $2; at[c] = k }
    if ($2 > worst) { worst = $2; worst_at = k; worst_class = c }
    steps++
  }
  END {
    if (steps == 0) { print "step-cost: no step was measured"; exit 2 }
    printf "  %-12s %8s %8s %8s  %s\n", "class", "steps", "mean", "max", "at step"
    split("idle injecting transition sweep calibration pair event", order, " ")
    for (i = 1; i <= 7; ++i) {
      c = order[i]
      if (n[c] > 0) printf "  %-12s %8d %8.0f %8d  %d\n", c, n[c], sum[c] / n[c], max[c], at[c]
    }
    printf "step-cost: worst step %d instructions (step %d, %s) over %d steps\n", worst, worst_at, worst_class, steps
    if (budget != "") {
      if (worst > budget) { printf "step-cost: FAIL: above the budget of %d instructions\n", budget; exit 1 }
      printf "step-cost: PASS: every step within the budget of %d instructions\n", budget
    }
  }' "$work/callgrind.out"
