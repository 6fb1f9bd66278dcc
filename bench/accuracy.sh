#!/usr/bin/env bash
# Reproduces the figures of docs/accuracy.md: every benchmark scenario side by side, as one
# Markdown table on stdout and a plot per scenario in docs/accuracy/.
#   bench/accuracy.sh [BUILD_DIR]     (default build/release; built if missing)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build/release}
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
)
"$build/tools/pmsm-thermal" simulate "${scenarios[@]}" --markdown --plot-dir docs/accuracy --quiet
