#!/usr/bin/env python3
"""Writes the default asset's held-out raw volume (docs/scale.md, "The default asset"): a
23x19x27 float32 raw grid (x fastest) for `--spacing 0.04`, five Gaussian puffs of random
centres, sizes and peaks (seed 11) with a hard-edged slab cut through them: a volume none of
the rule's constants were measured on. Pure Python, no dependencies.

Usage: scripts/holdout_volume.py OUT_DIR   (writes OUT_DIR/holdout_23x19x27_float32.raw)
"""
import math
import random

from raw_volume import write_raw

rng = random.Random(11)
PUFFS = [
    (
        (rng.uniform(0.25, 0.75), rng.uniform(0.25, 0.75), rng.uniform(0.25, 0.75)),
        rng.uniform(10.0, 50.0),
        rng.uniform(0.05, 0.15),
    )
    for _ in range(5)
]


def density(x, y, z):
    total = 0.0
    for (cx, cy, cz), peak, sigma in PUFFS:
        r2 = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2
        total += peak * math.exp(-r2 / (2 * sigma**2))
    if 0.4 < y < 0.55:
        total *= 0.2
    return total


def main():
    write_raw(__doc__, "holdout", (23, 19, 27), density)


if __name__ == "__main__":
    main()
