"""Entry point of the ``pinrt-vdb-worker`` script: pinbake's isolated OpenVDB reader.

Imports nothing but the extension module: the worker runs under an address-space limit.
"""

import sys


def main() -> None:
    from pinrt._native import vdb_worker

    args = sys.argv[1:]
    if not args or args[0] != "__vdb-worker":
        sys.stderr.write("usage: pinrt-vdb-worker __vdb-worker FILE SELECTOR MODE\n")
        sys.exit(2)
    sys.exit(vdb_worker(args[1:]))
