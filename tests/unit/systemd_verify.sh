#!/usr/bin/env bash
# systemd-analyze verify on every unit of systemd/, as the instances a deployment uses
# (pmsm-thermald@axis1, pmsm-plant@axis1), with the executables pointed at this build.
# Any message from systemd-analyze is a failure. Exit 77 (a visible skip) without it.
#   tests/unit/systemd_verify.sh SOURCE_DIR THERMALD_EXE PLANT_EXE
set -euo pipefail
src=$1 thermald=$2 plant=$3
if ! command -v systemd-analyze >/dev/null; then
  echo "systemd-analyze is not installed: skipped" >&2
  exit 77
fi
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
sed -e "s#/usr/sbin/pmsm-thermald#$thermald#g" "$src/systemd/pmsm-thermald@.service" > "$dir/pmsm-thermald@axis1.service"
sed -e "s#/usr/bin/pmsm-plant#$plant#g" "$src/systemd/pmsm-plant@.service" > "$dir/pmsm-plant@axis1.service"
status=0
for unit in "$dir"/*.service; do
  out=$(systemd-analyze verify --man=no "$unit" 2>&1) || status=1
  # Messages about units this one refers to but that are not installed here are not about
  # our files; everything else is.
  out=$(printf '%s\n' "$out" | grep -v -e '^$' || true)
  if [ -n "$out" ]; then
    echo "$(basename "$unit"):"
    printf '%s\n' "$out"
    status=1
  else
    echo "$(basename "$unit"): clean"
  fi
done
exit $status
