#!/usr/bin/env bash
# Reproduces docs/accuracy.md, "The robustness suite under the other methods": every scenario
# of bench/scenarios/robustness under fixed-angle bipolar, fixed-angle unipolar and
# fixed-magnitude unipolar injection (copies that set only [controller.injection] method and
# separation; the calibration stays fixed-magnitude bipolar), as one Markdown table on stdout.
#   [JOBS=N] bench/other-methods.sh [BUILD_DIR]     (default build/release; built if missing)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build/release}
jobs=${JOBS:-$(nproc)}
if [ ! -x "$build/tools/pmsm-thermal" ]; then
  cmake --preset release >/dev/null
  cmake --build --preset release --target pmsm-thermal
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
copies=()
for scenario in bench/scenarios/robustness/*.toml; do
  name=$(basename "$scenario" .toml)
  for variant in "fixed-angle bipolar fa-bi" "fixed-angle unipolar fa-uni" "fixed-magnitude unipolar fm-uni"; do
    read -r method separation tag <<<"$variant"
    copy="$work/${name}__${tag}.toml"
    printf '[scenario]\nbase = "%s"\nname = "%s %s"\n[controller.injection]\nmethod = "%s"\nseparation = "%s"\n' \
      "$PWD/$scenario" "$name" "$tag" "$method" "$separation" >"$copy"
    copies+=("$copy")
  done
done
"$build/tools/pmsm-thermal" simulate -j "$jobs" --markdown --quiet "${copies[@]}"
