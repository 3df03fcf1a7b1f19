#!/usr/bin/env python3
"""Writes a cloudscape scene file (docs/scene.md): COUNT overlapping instances of the given
assets, scattered over a sky slab with a turn about the vertical, a small tilt and a
non-uniform scale each, from a fixed seed (the same file for the same arguments).

Usage: scripts/cloudscape_scene.py OUT.json COUNT SEED NAME=VOLUME[,PINS] [NAME=...]...

VOLUME and PINS are written as given (relative paths are relative to OUT.json's folder).
The slab grows with the count so that a ray meets a similar number of clouds at every
count: its side is 2 * sqrt(COUNT) cloud sizes, and a cloud size is 10 units (the
production generator's clouds span 10 units along their longest axis, whatever their voxel
counts). Pure Python, no dependencies.
"""
import json
import math
import random
import sys


def main(argv):
    if len(argv) < 5:
        sys.exit(__doc__)
    out, count, seed = argv[1], int(argv[2]), int(argv[3])
    if count < 1:
        sys.exit("cloudscape_scene.py: COUNT must be at least 1")
    assets = {}
    for spec in argv[4:]:
        name, _, files = spec.partition("=")
        volume, _, pins = files.partition(",")
        asset = {"volume": volume}
        if pins:
            asset["pins"] = pins
        assets[name] = asset
    rng = random.Random(seed)
    names = sorted(assets)
    # scripts/production/cloud.cpp: 10 units along the longest axis.
    size = 10.0
    side = math.sqrt(count) * size
    instances = []
    for i in range(count):
        s = rng.uniform(0.6, 1.4)
        instances.append(
            {
                "asset": names[i % len(names)],
                "transform": {
                    "translate": [
                        round(rng.uniform(-side, side), 3),
                        round(rng.uniform(0.0, 0.6 * size), 3),
                        round(rng.uniform(-side, side), 3),
                    ],
                    "rotate_deg": [
                        round(rng.uniform(-8.0, 8.0), 3),
                        round(rng.uniform(0.0, 360.0), 3),
                        round(rng.uniform(-8.0, 8.0), 3),
                    ],
                    "scale": [
                        round(s * rng.uniform(0.85, 1.25), 4),
                        round(s * rng.uniform(0.8, 1.0), 4),
                        round(s * rng.uniform(0.85, 1.25), 4),
                    ],
                },
            }
        )
    scene = {
        "assets": assets,
        "instances": instances,
        # From above the slab's edge, looking across it and down a little.
        "camera": {
            "origin": [0.0, 2.5 * size, -side - 3.0 * size],
            "target": [0.0, 0.3 * size, 0.0],
            "fov": 50.0,
        },
        "sun": {"direction": [0.4, 1.0, 0.3], "radiance": 3.0},
        "env_radiance": 0.3,
        "albedo": 0.9,
    }
    with open(out, "w") as f:
        json.dump(scene, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv)
