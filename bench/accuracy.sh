#!/usr/bin/env bash
# Reproduces the figures of docs/accuracy.md: every benchmark scenario side by side, the
# reference heat-up's seed spread and the robustness suite, as Markdown tables on stdout and a
# plot per scenario in docs/accuracy/.
#   [JOBS=N] bench/accuracy.sh [BUILD_DIR]     (default build/release; built if missing)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build/release}
jobs=${JOBS:-$(nproc)}   # scenarios at a time (simulate -j); each steps its twin on a second thread
if [ ! -x "$build/tools/pmsm-thermal" ]; then
  cmake --preset release >/dev/null
  cmake --build --preset release --target pmsm-thermal
fi
scenarios=(
  bench/scenarios/reference-fm-bipolar.toml
  bench/scenarios/reference-fm-unipolar.toml
  bench/scenarios/reference-fa-bipolar.toml
  bench/scenarios/reference-fa-unipolar.toml
  bench/scenarios/reference-dc.toml
  bench/scenarios/reference-no-injection.toml
  bench/scenarios/reference-model-only.toml
  bench/scenarios/salient-fm-bipolar.toml
  bench/scenarios/standstill-fm-bipolar.toml
  bench/scenarios/load-steps-fm-bipolar.toml
  bench/scenarios/rated-speed-fm-bipolar.toml
)
echo "## Benchmark scenarios"
echo
"$build/tools/pmsm-thermal" simulate -j "$jobs" "${scenarios[@]}" --markdown --plot-dir docs/accuracy --quiet
echo
echo "## The reference heat-up, seeds 11-18"
echo
"$build/tools/pmsm-thermal" simulate -j "$jobs" bench/scenarios/seeds/reference-fm-bipolar-seed1[1-8].toml --markdown --quiet
if compgen -G "bench/scenarios/robustness/*.toml" > /dev/null; then
  echo
  echo "## Robustness suite (other motors, ambients, restarts, duty cycles)"
  echo
  "$build/tools/pmsm-thermal" simulate -j "$jobs" bench/scenarios/robustness/*.toml --markdown --plot-dir docs/accuracy/robustness --quiet
fi
echo
echo "## Self-ventilated machines (a shaft fan; the drive told of it, and not)"
echo
"$build/tools/pmsm-thermal" simulate -j "$jobs" bench/scenarios/self-ventilated/*.toml --markdown --quiet
