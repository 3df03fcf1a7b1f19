#!/usr/bin/env python3
"""Writes the `torus` test volume of docs/evaluation.md ("Chained lookups and the lookup
point"): a 48x40x44 float32 raw grid (x fastest) for `--spacing 0.025`, holding a torus
tilted 35 degrees about x (radii 0.3 and 0.1 of the unit cube, density 25, hard edge) and an
off-centre Gaussian knot (peak 60, sigma 0.07). Pure Python, no dependencies.

Usage: scripts/torus_volume.py OUT_DIR   (writes OUT_DIR/torus_48x40x44_float32.raw)
"""
import math

from raw_volume import write_raw

NX, NY, NZ = 48, 40, 44


def density(x, y, z):
    a = math.radians(35)
    px, py, pz = x - 0.5, y - 0.5, z - 0.5
    qx = px
    qy = math.cos(a) * py - math.sin(a) * pz
    qz = math.sin(a) * py + math.cos(a) * pz
    tube = math.hypot(math.hypot(qx, qy) - 0.3, qz)
    v = 25.0 if tube < 0.1 else 0.0
    r2 = (x - 0.7) ** 2 + (y - 0.35) ** 2 + (z - 0.6) ** 2
    return v + 60.0 * math.exp(-r2 / (2 * 0.07**2))


def main():
    write_raw(__doc__, "torus", (NX, NY, NZ), density)


if __name__ == "__main__":
    main()
