#!/usr/bin/env bash
# The no-load Rs bias study of docs/accuracy.md ("The reference's positive mean, traced"):
# the reference machine held at one speed, its thermal network frozen (Rs = 133 mOhm
# throughout), 100 s of 1 s events without a calibration run (the events learn Vx themselves),
# with the trapezoidal and the sinusoidal EMF, a free shaft or an ideal dynamometer.
# Prints the mean Rs error of the published estimates after 3 s (22 s under load) with its
# standard error. About 40 s on 2 cores.
#
# usage: bench/no-load-bias.sh [BUILD_DIR]      (default build/dev)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build/dev}
tool=$build/tools/pmsm-thermal
[ -x "$tool" ] || { echo "no-load-bias: $tool not built" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# scenario NAME SPEED LOAD_STEPS "EXTRA TOML"
scenario() {
  cat >"$work/$1.toml" <<EOF
[scenario]
base = "$root/bench/scenarios/reference-fm-bipolar.toml"
name = "$1"
duration_s = 100.0
[operation]
calibrate = false
speed_rad_s = [[0.0, 0.0], [0.4, $2], [100.0, $2]]
[plant.load]
steps = $3
[plant.thermal]
enabled = false
$4
EOF
}
# An ideal dynamometer holds the speed; the drive runs in torque mode at 0 Nm (no speed loop).
dyno() {
  cat >"$work/$1.toml" <<EOF
[scenario]
name = "$1"
duration_s = 100.0
thermal_acceleration = 60.0
ambient_C = 25.0
seed = 11
[operation]
mode = "torque"
calibrate = false
torque_Nm = [[0.0, 0.0], [100.0, 0.0]]
[plant]
profile = "$root/plant-emulator/profiles/reference.toml"
[plant.load]
profile = "speed"
speed_rad_s = $2
[plant.thermal]
enabled = false
[controller.injection]
method = "fixed-magnitude"
separation = "bipolar"
levels = [1.0, 0.4]
interval_s = 1.0
[controller.motor]
ld_H = 6.05e-3
lq_H = 4.95e-3
ke_V_s_per_rad = 1.2257
$3
EOF
}
sine=$'[plant.emf]\nshape = "sinusoidal"'
exact=$'[controller.motor]\nld_H = 5.5e-3\nlq_H = 5.5e-3'
both="$exact"$'\n'"$sine"
noload='[[0.0, 0.0]]'
loaded='[[0.0, 0.0], [20.0, 60.0]]'
names=()
for sp in 30 60 120; do
  scenario "trap-$sp" "$sp" "$noload" ""; scenario "sine-$sp" "$sp" "$noload" "$sine"
  names+=("trap-$sp" "sine-$sp")
done
scenario trap-60-exact-L 60 "$noload" "$exact"; scenario sine-60-exact-L 60 "$noload" "$both"
dyno trap-60-dyno 60 ""; dyno sine-60-dyno 60 "$sine"
scenario trap-60-loaded 60 "$loaded" ""; scenario sine-60-loaded 60 "$loaded" "$sine"
names+=(trap-60-exact-L sine-60-exact-L trap-60-dyno sine-60-dyno trap-60-loaded sine-60-loaded)

files=()
for n in "${names[@]}"; do files+=("$work/$n.toml"); done
"$tool" simulate --quiet -j 2 --events "${files[@]}" >"$work/events.txt"

# The events of each scenario precede its name line ("NAME — method"); rows have 17 fields
# (time_s, age_s, speed, iq, rs_est, std, rs_true at the estimate's own time, ..., fused);
# the fused ones count (the last column is "yes", or "gated").
awk '
  NF == 17 && $17 == "yes" { t[++n] = $1; est[n] = $5; tru[n] = $7; next }
  / — / {
    name = $1; from = (name ~ /loaded/) ? 22 : 3; m = 0; s = 0; s2 = 0; tt = 0
    for (k = 1; k <= n; ++k) if (t[k] > from) { e = (est[k] / tru[k] - 1) * 100; s += e; s2 += e * e; ++m }
    if (m > 1) { mu = s / m; sd = sqrt((s2 - m * mu * mu) / (m - 1)); printf "%-18s %3d estimates  Rs error %+.3f %% +- %.3f\n", name, m, mu, sd / sqrt(m) }
    n = 0
  }' "$work/events.txt" >"$work/figures.txt"
# A layout change of --events must not pass as "no figures": every scenario reports a row.
if [ "$(wc -l <"$work/figures.txt")" -ne "${#names[@]}" ]; then
  echo "no-load-bias: expected ${#names[@]} figures, parsed $(wc -l <"$work/figures.txt") from simulate --events" >&2
  exit 1
fi
cat "$work/figures.txt"
