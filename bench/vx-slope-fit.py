#!/usr/bin/env python3
"""Fits a run's estimate errors to the bridge's bus-slope error (docs/accuracy.md, round 14, f3).

A dead time commissioned off by dt refers the bridge's voltage error Vx to a moving bus by a
slope off by dt x f_pwm; under load, where no event can learn Vx again, an estimate then reads
off by about that slope x (Vdc - Vdc at the calibration) / |iq|. This script reads
`pmsm-thermal simulate SCENARIO --events` (every estimate with the truth beside it), takes Vdc
from the scenario's `plant.inverter.dc_source_points` (the source's schedule, not the bus the
drive saw) and fits err_mohm = c x (Vdc - Vdc_cal) / |iq_A| through the origin.

    pmsm-thermal simulate S.toml --events > events.txt
    bench/vx-slope-fit.py S.toml events.txt
"""
import sys
import tomllib
from pathlib import Path


def load_scenario(path: Path) -> dict:
    with open(path, "rb") as f:
        table = tomllib.load(f)
    base = table.get("scenario", {}).get("base")
    if base is None:
        return table
    merged = load_scenario(path.parent / base)

    def merge(into: dict, over: dict) -> None:
        for key, value in over.items():
            if isinstance(value, dict) and isinstance(into.get(key), dict):
                merge(into[key], value)
            else:
                into[key] = value

    merge(merged, table)
    return merged


def interpolate(points: list, t: float) -> float:
    if t <= points[0][0]:
        return points[0][1]
    for (t0, v0), (t1, v1) in zip(points, points[1:]):
        if t <= t1:
            return v1 if t1 == t0 else v0 + (v1 - v0) * (t - t0) / (t1 - t0)
    return points[-1][1]


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    scenario = load_scenario(Path(sys.argv[1]))
    inverter = scenario.get("plant", {}).get("inverter", {})
    points = inverter.get("dc_source_points") or [[0.0, inverter.get("dc_bus_V", 650.0)]]
    t_cal = scenario.get("operation", {}).get("calibrate_at_s", 0.5)
    v_cal = interpolate(points, t_cal)
    xs, ys = [], []
    with open(sys.argv[2]) as f:
        for line in f:
            cols = line.split()
            if len(cols) < 17 or not cols[0][0].isdigit():
                continue
            try:
                t, iq, err = float(cols[0]), float(cols[3]), float(cols[7])
            except ValueError:
                continue
            if abs(iq) < 5.0 or t < t_cal + 2.0:
                continue
            xs.append((interpolate(points, t) - v_cal) / abs(iq))
            ys.append(err)
    if not xs or sum(x * x for x in xs) == 0.0:
        print("no estimate away from the calibration's bus under load", file=sys.stderr)
        return 1
    c = sum(x * y for x, y in zip(xs, ys)) / sum(x * x for x in xs)
    residual = sum((y - c * x) ** 2 for x, y in zip(xs, ys))
    total = sum(y * y for y in ys)
    print(f"{len(xs)} estimates, mean error {sum(ys) / len(ys):+.2f} mOhm; "
          f"err = {c / 1000:+.5f} V/V x (Vdc - {v_cal:.0f} V) / |iq| through the origin, R2 {1 - residual / total:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
