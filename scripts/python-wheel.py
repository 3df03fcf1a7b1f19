#!/usr/bin/env python3
"""Packs the Python package into a wheel around an extension module cargo has already built.

    python-wheel.py EXTENSION OUT_DIR

EXTENSION is the `_native` cdylib of the workspace's release build (target/release/
lib_native.so); the wheel holds it as pinrt/_native.abi3.so beside python/py/pinrt/, with the
metadata, the console script and the tag that `maturin build` gives the same package
(python/pyproject.toml). scripts/test.sh installs this wheel: maturin would compile the
extension's dependency tree a second time with the features of the extension alone, about
200 s of CPU on 2 cores, where the workspace's build has already compiled it with the
workspace's features. scripts/python-test.sh without --prebuilt builds the wheel with
maturin, as a user or a release does (docs/decisions.md D4).
"""

import base64
import hashlib
import os
import sys
import sysconfig
import tomllib
import zipfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PYTHON = os.path.join(REPO, "python")


def record_line(name, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def main():
    if len(sys.argv) != 3:
        print("usage: python-wheel.py EXTENSION OUT_DIR", file=sys.stderr)
        return 2
    extension, out_dir = sys.argv[1], sys.argv[2]
    with open(os.path.join(PYTHON, "pyproject.toml"), "rb") as f:
        pyproject = tomllib.load(f)
    project = pyproject["project"]
    maturin = pyproject["tool"]["maturin"]
    name, version = project["name"], project["version"]
    package, module = maturin["module-name"].rsplit(".", 1)
    source = os.path.join(PYTHON, maturin["python-source"], package)
    try:
        with open(extension, "rb") as f:
            native = f.read()
    except OSError as e:
        print(f"{extension}: {e.strerror} (build the workspace first)", file=sys.stderr)
        return 1

    files = []
    for entry in sorted(os.listdir(source)):
        path = os.path.join(source, entry)
        if os.path.isfile(path) and not entry.endswith((".pyc", ".so")):
            with open(path, "rb") as f:
                files.append((f"{package}/{entry}", f.read()))
    files.append((f"{package}/{module}.abi3.so", native))

    # The abi3 floor from requires-python (">=3.9" gives cp39), as maturin tags it.
    floor = project["requires-python"].removeprefix(">=").strip().split(".")
    abi_tag = f"cp{floor[0]}{floor[1]}-abi3"
    platform = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    tag = f"{abi_tag}-{platform}"
    dist_info = f"{name}-{version}.dist-info"
    metadata = [
        "Metadata-Version: 2.1",
        f"Name: {name}",
        f"Version: {version}",
        f"Summary: {project['description']}",
        f"License: {project['license']['text']}",
        f"Requires-Python: {project['requires-python']}",
        *(f"Requires-Dist: {d}" for d in project.get("dependencies", [])),
        *(f"Classifier: {c}" for c in project.get("classifiers", [])),
    ]
    scripts = project.get("scripts", {})
    files.append((f"{dist_info}/METADATA", ("\n".join(metadata) + "\n").encode()))
    wheel = f"Wheel-Version: 1.0\nGenerator: pinrt python-wheel.py\nRoot-Is-Purelib: false\nTag: {tag}\n"
    files.append((f"{dist_info}/WHEEL", wheel.encode()))
    if scripts:
        lines = "".join(f"{k} = {v}\n" for k, v in scripts.items())
        files.append((f"{dist_info}/entry_points.txt", f"[console_scripts]\n{lines}".encode()))
    record = "".join(record_line(n, d) + "\n" for n, d in files) + f"{dist_info}/RECORD,,\n"
    files.append((f"{dist_info}/RECORD", record.encode()))

    os.makedirs(out_dir, exist_ok=True)
    wheel_path = os.path.join(out_dir, f"{name}-{version}-{tag}.whl")
    with zipfile.ZipFile(wheel_path, "w", zipfile.ZIP_DEFLATED) as z:
        for n, d in files:
            info = zipfile.ZipInfo(n, date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = (0o755 if n.endswith(".so") else 0o644) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, d)
    print(wheel_path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
