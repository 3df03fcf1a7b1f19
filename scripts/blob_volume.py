#!/usr/bin/env python3
"""Writes the `blob` test volume of the direction sweeps (docs/evaluation.md): a 40x44x36
float32 raw grid (x fastest) for `--spacing 0.025`, two Gaussians in unit-cube coordinates,
peak 80 (sigma 0.12) at (0.45, 0.5, 0.5) and peak 60 (sigma 0.06) at (0.68, 0.38, 0.6).
Pure Python, no dependencies.

Usage: scripts/blob_volume.py OUT_DIR   (writes OUT_DIR/blob_40x44x36_float32.raw)
"""
import math

from raw_volume import write_raw

NX, NY, NZ = 40, 44, 36
BUMPS = [((0.45, 0.5, 0.5), 80.0, 0.12), ((0.68, 0.38, 0.6), 60.0, 0.06)]


def density(x, y, z):
    total = 0.0
    for (cx, cy, cz), peak, sigma in BUMPS:
        r2 = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2
        total += peak * math.exp(-r2 / (2 * sigma**2))
    return total


def main():
    write_raw(__doc__, "blob", (NX, NY, NZ), density)


if __name__ == "__main__":
    main()
