#!/usr/bin/env python3
"""Writes the `torus` test volume of docs/evaluation.md ("Chained lookups and the lookup
point"): a 48x40x44 float32 raw grid (x fastest) for `--spacing 0.025`, holding a torus
tilted 35 degrees about x (radii 0.3 and 0.1 of the unit cube, density 25, hard edge) and an
off-centre Gaussian knot (peak 60, sigma 0.07). Pure Python, no dependencies.

Usage: scripts/torus_volume.py OUT_DIR   (writes OUT_DIR/torus_48x40x44_float32.raw)
"""
import array
import math
import os
import sys

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
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = array.array("f")
    for k in range(NZ):
        for j in range(NY):
            for i in range(NX):
                out.append(density((i + 0.5) / NX, (j + 0.5) / NY, (k + 0.5) / NZ))
    if sys.byteorder != "little":
        out.byteswap()
    path = os.path.join(sys.argv[1], f"torus_{NX}x{NY}x{NZ}_float32.raw")
    with open(path, "wb") as f:
        f.write(out.tobytes())
    print(path)


if __name__ == "__main__":
    main()
