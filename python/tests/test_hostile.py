"""Hostile and careless use of the Python package: every case gives a clean exception in
bounded time and memory, and replaces nothing the caller did not name as output. The rules
are the Rust library's (``pinbake::plan``, ``pin_format::input``), reached through the same
code as the ``pinbake`` command; each test fails when its rule is taken out of that code."""

from __future__ import annotations

import math
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pinrt
from pinrt import PinError, PinGrid, _native

SMALL = dict(cells=4, directions="octahedral:2", step=0.05)


def blob() -> np.ndarray:
    x = np.linspace(-1, 1, 8, dtype=np.float32)
    return np.exp(-4 * (x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2))


@pytest.fixture(scope="module")
def pin(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("hostile") / "blob.pin"
    pinrt.bake(blob(), out, **SMALL)
    return out


def raw_input(tmp_path: Path) -> Path:
    p = tmp_path / "blob_8x8x8_float32.raw"
    p.write_bytes(np.ascontiguousarray(blob().transpose(2, 1, 0)).tobytes())
    return p


def test_the_input_is_never_the_output(tmp_path):
    src = raw_input(tmp_path)
    before = src.read_bytes()
    with pytest.raises(PinError, match="is the input file"):
        pinrt.bake(src, src, **SMALL)
    link = tmp_path / "link.pin"
    link.symlink_to(src)
    with pytest.raises(PinError, match="is the input file"):
        pinrt.bake(src, link, **SMALL)
    assert src.read_bytes() == before


def test_special_outputs_are_refused_and_kept(tmp_path):
    fifo = tmp_path / "fifo.pin"
    os.mkfifo(fifo)
    with pytest.raises(PinError, match="not a regular file"):
        pinrt.bake(blob(), fifo, **SMALL)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(PinError, match="not a regular file"):
        pinrt.bake(blob(), "/dev/null", **SMALL)
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    dangling = tmp_path / "dangling.pin"
    dangling.symlink_to(tmp_path / "nowhere.pin")
    with pytest.raises(PinError, match="symlink to a missing file"):
        pinrt.bake(blob(), dangling, **SMALL)
    assert dangling.is_symlink() and not (tmp_path / "nowhere.pin").exists()
    with pytest.raises(PinError, match="is a directory"):
        pinrt.bake(blob(), tmp_path, **SMALL)


def test_a_symlink_to_a_file_is_followed(tmp_path):
    target = tmp_path / "real.pin"
    target.write_bytes(b"old")
    link = tmp_path / "link.pin"
    link.symlink_to(target)
    pinrt.bake(blob(), link, **SMALL)
    assert link.is_symlink(), "the link stays"
    assert target.read_bytes()[:4] != b"old", "the file it points to is replaced"
    PinGrid(link).verify()


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "grid.pin"
    os.mkfifo(fifo)
    # In a child with a timeout: a blocking open would hang the suite.
    code = f"import pinrt\ntry:\n    pinrt.PinGrid({str(fifo)!r})\nexcept pinrt.PinError as e:\n    print(e)\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert "not a regular file" in r.stdout, r.stdout + r.stderr
    with pytest.raises(PinError, match="is a directory"):
        PinGrid(tmp_path)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(spacing=1e300), "spacing"),
        (dict(spacing=0.0), "spacing"),
        (dict(origin=1e13), "origin"),
        (dict(step=1e-12), "step"),
        (dict(step=float("nan")), "step"),
        (dict(density_scale=-1.0), "density_scale"),
        (dict(threads=0), "threads"),
        (dict(threads=10**6), "threads"),
        (dict(pins_per_entry=0), "pins_per_entry"),
        (dict(target_error=2.0), "target_error"),
        (dict(majorant=5000), "majorant"),
        (dict(embed_control=0), "embed_control"),
        (dict(embed_control=65), "embed_control"),
        (dict(embed_control="fine"), "embed_control"),
        (dict(dims=8), "dims does not apply to an array"),
        (dict(grid="density"), "grid does not apply to an array"),
        (dict(clamp_negative=True), "clamp_negative does not apply"),
        (dict(endian="big"), "endian does not apply"),
    ],
)
def test_options_out_of_range_or_not_applying_are_value_errors(tmp_path, kwargs, message):
    out = tmp_path / "o.pin"
    opts = {**SMALL, **kwargs}
    with pytest.raises(ValueError, match=message):
        pinrt.bake(blob(), out, **opts)
    assert not out.exists()


def test_file_options_that_do_not_apply_are_refused(tmp_path):
    src = raw_input(tmp_path)
    with pytest.raises(ValueError, match="grid does not apply to a raw input"):
        pinrt.bake(src, tmp_path / "o.pin", grid="density", **SMALL)
    with pytest.raises(ValueError, match="dims does not apply to a procedural input"):
        pinrt.bake("procedural:box", tmp_path / "o.pin", dims=8, **SMALL)


def test_the_memory_budget_is_a_memory_error(tmp_path):
    out = tmp_path / "o.pin"
    with pytest.raises(MemoryError, match="memory budget"):
        pinrt.bake(blob(), out, max_memory=1000, **SMALL)
    assert not out.exists()


@pytest.mark.parametrize(
    "bad",
    [
        np.array(["2020-01-01"] * 6, dtype="datetime64[D]").reshape(2, 3),
        np.zeros((2,), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]),
        np.array([["a", "b", "c"], ["d", "e", "f"]]),
        np.ones((2, 3), dtype=bool),
        np.array([[object()] * 3] * 2, dtype=object),
    ],
)
def test_only_numeric_arrays_are_rays(pin, bad):
    g = PinGrid(pin)
    with pytest.raises(ValueError, match="integers or floats"):
        g.transmittance(bad, np.ones((2, 3)))
    with pytest.raises(ValueError, match="integers or floats"):
        g.sample_distance(np.ones((2, 3)), bad)


def test_t_max_none_is_refused(pin):
    g = PinGrid(pin)
    with pytest.raises(ValueError, match="t_max is None"):
        g.transmittance(np.zeros((4, 3)), np.ones((4, 3)), None)


def test_fortran_order_is_refused_by_native_and_right_through_the_api(pin):
    rng = np.random.default_rng(5)
    o = (rng.random((2000, 3), dtype=np.float32) * 12 - 6).astype(np.float32)
    d = rng.normal(size=(2000, 3)).astype(np.float32)
    t = np.full(2000, np.inf, dtype=np.float32)
    g = PinGrid(pin)
    native = g._g
    with pytest.raises(ValueError, match="C-contiguous"):
        native.transmittance(np.asfortranarray(o), d, t, 0, 0, 0.0, 0.0, 0, "start", False)
    with pytest.raises(ValueError, match="C-contiguous"):
        _native.bake("<array>", "x.pin", data=np.asfortranarray(np.zeros((4, 4, 4), np.float32)))
    c = g.transmittance(o, d, seed=3)
    f = g.transmittance(np.asfortranarray(o), np.asfortranarray(d), seed=3)
    assert np.array_equal(c, f)


def test_queries_beyond_memory_raise_memory_error(pin, tmp_path):
    # A child whose address space is capped just above what its arrays use: the queries'
    # own buffers do not fit, and must raise MemoryError instead of aborting.
    code = f"""
import resource, numpy as np, pinrt
g = pinrt.PinGrid({str(pin)!r})
n = 20_000_000
o = np.zeros((n, 3), np.float32); d = np.ones((n, 3), np.float32); t = np.full(n, np.inf, np.float32)
soft, hard = resource.getrlimit(resource.RLIMIT_AS)
used = int(open('/proc/self/statm').read().split()[0]) * resource.getpagesize()
resource.setrlimit(resource.RLIMIT_AS, (used + (256 << 20), hard))
try:
    g._g.transmittance(o, d, t, 0, 0, 0.0, 0.0, 0, "start", False)
    print("no error")
except MemoryError as e:
    print("MemoryError:", e)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "MemoryError" in r.stdout, r.stdout + r.stderr


def test_a_bake_leaves_ctrl_c_to_python(tmp_path):
    # A bake writes through a partial file; the library must not install signal handlers to
    # clean it up (the command-line tools do), or Ctrl-C would kill the interpreter instead of
    # raising KeyboardInterrupt. Run in a child so that a failure cannot end this test run.
    code = (
        "import os, signal, numpy as np, pinrt\n"
        "x = np.linspace(-1, 1, 8, dtype=np.float32)\n"
        "pinrt.bake(np.exp(-4 * (x[:, None, None] ** 2 + x[None, :, None] ** 2"
        " + x[None, None, :] ** 2)), os.environ['OUT'], cells=4, directions='octahedral:2',"
        " step=0.05)\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted')\n"
    )
    env = dict(os.environ, OUT=str(tmp_path / "a.pin"))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, (r.returncode, r.stderr)
    assert r.stdout.strip() == "interrupted"
    assert (tmp_path / "a.pin").is_file()
