"""The writer shared by the test-volume scripts (torus_volume.py, blob_volume.py): samples a
density at voxel centres of the unit cube and writes a little-endian float32 raw grid, x
fastest, named NAME_NXxNYxNZ_float32.raw. Pure Python, no dependencies."""
import array
import os
import sys


def write_raw(doc, name, dims, density):
    """Runs the calling script: `doc` is its usage text, printed when OUT_DIR is missing."""
    if len(sys.argv) != 2:
        sys.exit(doc)
    nx, ny, nz = dims
    out = array.array("f")
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                out.append(density((i + 0.5) / nx, (j + 0.5) / ny, (k + 0.5) / nz))
    if sys.byteorder != "little":
        out.byteswap()
    path = os.path.join(sys.argv[1], f"{name}_{nx}x{ny}x{nz}_float32.raw")
    with open(path, "wb") as f:
        f.write(out.tobytes())
    print(path)
