#!/usr/bin/env python3
"""How well the drive's saturation curve gives the incremental Lq from secants at a few loads.

The estimator learns the secant Lq as a - b s with s = u = (iq / current_limit)^2 (no flux map)
and takes the incremental d psi_q / d iq as a - 3 b u (docs/estimator.md section 5.1). Here the
q axis is the plant's knee, psi = Ls i + (L - Ls) ik x / sqrt(1 + x^2), x = i / ik
(plant-emulator/src/plant.cpp), for several knees and saturated inductances, and the curve is
fitted exactly to noise-free secants at the anchor loads: the error left is the shape's alone.
Three fits: anchors at 10 and 78 A (what the 30 mOhm IPM heat-up has: light load and its
314 rad/s cruise), at 10, 78 and 150 A with the same two-parameter curve (a heavy-load anchor
added), and at those three with a third parameter, a - b u - b2 u^2 (incremental
a - 3 b u - 5 b2 u^2). The current limit is 300 A. Run: python3 bench/lq-curve-shapes.py
(docs/accuracy.md, "An IPM without its flux map").
"""
import math

LIMIT_A = 300.0
L_H = 0.45e-3


def secant(i, ls, ik):
    x = i / ik
    return ls + (L_H - ls) / math.sqrt(1.0 + x * x)


def incremental(i, ls, ik):
    x = i / ik
    return ls + (L_H - ls) / (1.0 + x * x) ** 1.5


def least_squares(rows, values):
    n = len(rows[0])
    m = [[sum(r[a] * r[b] for r in rows) for b in range(n)] for a in range(n)]
    v = [sum(r[a] * y for r, y in zip(rows, values)) for a in range(n)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        m[c], m[p], v[c], v[p] = m[p], m[c], v[p], v[c]
        for r in range(n):
            if r != c:
                f = m[r][c] / m[c][c]
                m[r] = [a - f * b for a, b in zip(m[r], m[c])]
                v[r] -= f * v[c]
    return [v[i] / m[i][i] for i in range(n)]


def fitted_incremental(anchors, third, ls, ik, at_A):
    rows = []
    for i in anchors:
        u = (i / LIMIT_A) ** 2
        rows.append([1.0, -u, -u * u] if third else [1.0, -u])
    p = least_squares(rows, [secant(i, ls, ik) for i in anchors])
    u = (at_A / LIMIT_A) ** 2
    return p[0] - 3.0 * p[1] * u - (5.0 * p[2] * u * u if third else 0.0)


def main():
    fits = [((10.0, 78.0), False), ((10.0, 78.0, 150.0), False), ((10.0, 78.0, 150.0), True)]
    print("| knee / limit | Ls / L | anchors 10, 78 A | 10, 78, 150 A | 10, 78, 150 A with b2 u^2 |")
    print("|---|---|---|---|---|")
    for knee in (0.5, 0.73, 1.0, 1.5):
        for share in (0.5, 0.67, 0.8):
            ls, ik = share * L_H, knee * LIMIT_A
            cells = []
            for anchors, third in fits:
                errors = [100.0 * (fitted_incremental(anchors, third, ls, ik, a) / incremental(a, ls, ik) - 1.0)
                          for a in (78.0, 150.0)]
                cells.append(" / ".join(f"{e:+.2f}" for e in errors))
            print(f"| {knee:.2f} | {share:.2f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
