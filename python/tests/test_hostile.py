"""Hostile and careless use of the Python package: every case gives a clean exception in
bounded time and memory, and replaces nothing the caller did not name as output. The rules
are the Rust library's (``pinbake::plan``, ``pin_format::input``), reached through the same
code as the ``pinbake`` command; each test fails when its rule is taken out of that code."""

from __future__ import annotations

import math
import time
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
    # The child restores Python's own SIGINT handler first: started from a background job
    # of a non-interactive shell it inherits SIGINT ignored, and Python then installs none.
    code = (
        "import os, signal, numpy as np, pinrt\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
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


# --- Budgets, interrupts, placement, ranges and messages --------------------------------


def test_max_memory_counts_the_array_copy_before_making_it(tmp_path):
    # 2^26 voxels that hold 4 bytes: the bake's f32 copy is 256 MiB, over a 64 MiB budget.
    out = tmp_path / "o.pin"
    huge = np.broadcast_to(np.float32(1.0), (512, 512, 256))
    with pytest.raises(MemoryError, match="volume array"):
        pinrt.bake(huge, out, max_memory=64 << 20, **SMALL)
    assert not out.exists()
    # float16 is converted in Python: that copy is counted too, before it is made.
    with pytest.raises(MemoryError, match="volume array"):
        pinrt.bake(np.broadcast_to(np.float16(1.0), (512, 512, 256)), out, max_memory=64 << 20, **SMALL)


def test_any_memory_order_bakes_the_same_bytes(tmp_path):
    b = blob()
    ref = tmp_path / "c.pin"
    pinrt.bake(b, ref, **SMALL)
    for name, a in [
        ("fortran", np.asfortranarray(b)),
        ("strided", np.repeat(b, 2, axis=0)[::2]),
        ("float64", b.astype(np.float64)),
    ]:
        out = tmp_path / f"{name}.pin"
        pinrt.bake(a, out, **SMALL)
        assert out.read_bytes() == ref.read_bytes(), name
    half = b.astype(np.float16)
    pinrt.bake(half, tmp_path / "h16.pin", **SMALL)
    pinrt.bake(half.astype(np.float32), tmp_path / "h32.pin", **SMALL)
    assert (tmp_path / "h16.pin").read_bytes() == (tmp_path / "h32.pin").read_bytes()
    flat = np.broadcast_to(np.float32(0.5), (8, 8, 8))
    pinrt.bake(flat, tmp_path / "b.pin", **SMALL)
    pinrt.bake(np.full((8, 8, 8), 0.5, np.float32), tmp_path / "f.pin", **SMALL)
    assert (tmp_path / "b.pin").read_bytes() == (tmp_path / "f.pin").read_bytes()


def test_a_masked_array_is_refused_naming_the_mask(tmp_path):
    b = blob()
    masked = np.ma.masked_greater(b, 0.5)
    with pytest.raises(ValueError, match="mask"):
        pinrt.bake(masked, tmp_path / "m.pin", **SMALL)
    assert not (tmp_path / "m.pin").exists()
    # Nothing masked: its data, baked as the plain array.
    pinrt.bake(np.ma.masked_array(b), tmp_path / "n.pin", **SMALL)
    pinrt.bake(b, tmp_path / "p.pin", **SMALL)
    assert (tmp_path / "n.pin").read_bytes() == (tmp_path / "p.pin").read_bytes()


@pytest.mark.parametrize("backend", ["cpu", "gpu"])
def test_ctrl_c_stops_a_bake_within_a_second_and_leaves_nothing(tmp_path, backend):
    # A bake of minutes (1e4 steps per pin); SIGINT after 1 s must end it within a second,
    # as KeyboardInterrupt, with no output and no temp file. The GPU bake polls between
    # dispatches, which a cancellable bake keeps short (it took 14-16 s with one dispatch).
    # Python's own SIGINT handler first, as above (a background job inherits SIGINT ignored).
    code = (
        "import os, signal, threading, time, numpy as np, pinrt\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "a = np.random.default_rng(1).random((32, 32, 32), dtype=np.float32)\n"
        "sent = []\n"
        "def fire():\n"
        "    time.sleep(1.5)\n"
        "    sent.append(time.monotonic())\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "threading.Thread(target=fire, daemon=True).start()\n"
        "try:\n"
        "    pinrt.bake(a, os.environ['OUT'], cells=16, directions='octahedral:16', step=1e-4,"
        " backend=os.environ['BACKEND'])\n"
        "    print('finished')\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted %.3f' % (time.monotonic() - sent[0]))\n"
    )
    env = dict(os.environ, OUT=str(tmp_path / "slow.pin"), BACKEND=backend)
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    words = r.stdout.split()
    assert words[0] == "interrupted", r.stdout + r.stderr
    assert float(words[1]) < 1.0, f"stopped {words[1]} s after the signal"
    assert os.listdir(tmp_path) == [], os.listdir(tmp_path)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("procedural:box:extent=1e39", "beyond"),
        ("procedural:box:extent=1e-300", "wide"),
        ("procedural:sphere:radius=1e20", "beyond"),
    ],
)
def test_placement_outside_f32_is_refused_at_bake(tmp_path, spec, message):
    out = tmp_path / "o.pin"
    with pytest.raises(PinError, match=message) as e:
        pinrt.bake(spec, out, **SMALL)
    assert len(str(e.value)) < 300, str(e.value)
    assert not out.exists()


def test_array_placement_outside_f32_is_a_value_error(tmp_path):
    # Each value in its own range, together a box 1e-8 wide at 1e12: f32 cannot tell it apart.
    with pytest.raises(ValueError, match="spacing and origin"):
        pinrt.bake(blob(), tmp_path / "o.pin", spacing=1e-9, origin=1e12, **SMALL)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(max_memory=-1), "max_memory"),
        (dict(max_memory=0), "max_memory"),
        (dict(max_memory=2**64), "max_memory"),
        (dict(seed=-1), "seed"),
        (dict(seed=2**64), "seed"),
        (dict(cells=-1), "cells"),
        (dict(cells=(4, 4, 2**32)), "cells"),
        (dict(threads=-1), "threads"),
        (dict(embed_density=2**32), "embed_density"),
        (dict(majorant=-1), "majorant"),
        (dict(pins_per_entry=-1), "pins_per_entry"),
        (dict(embed_control=-1), "embed_control"),
        (dict(embed_control=2**40), "embed_control"),
        (dict(embed_control=1.5), "embed_control"),
        (dict(seed=2**1000), "seed"),
    ],
)
def test_out_of_range_integers_are_value_errors(tmp_path, kwargs, name):
    out = tmp_path / "o.pin"
    with pytest.raises(ValueError, match=name) as e:
        pinrt.bake(blob(), out, **{**SMALL, **kwargs})
    assert type(e.value) is ValueError
    assert len(str(e.value)) < 120, str(e.value)
    assert not out.exists()


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(seed=-1), "seed"),
        (dict(seed=2**32), "seed"),
        (dict(first_index=-1), "first_index"),
        (dict(first_index=2**32), "first_index"),
        (dict(chain_stride=-1), "chain_stride"),
        (dict(nearest_line=2**32), "nearest_line"),
        (dict(seed=1.5), "seed"),
    ],
)
def test_out_of_range_query_options_are_value_errors(pin, kwargs, name):
    g = PinGrid(pin)
    for query in (g.transmittance, g.sample_distance):
        with pytest.raises(ValueError, match=name) as e:
            query(np.zeros((2, 3)), np.ones((2, 3)), **kwargs)
        assert type(e.value) is ValueError


def test_open_out_of_address_space_is_a_memory_error(pin, tmp_path):
    # A pin file made 4 GiB long (sparse, no disk), opened under an address-space limit.
    big = tmp_path / "big.pin"
    big.write_bytes(pin.read_bytes())
    os.truncate(big, 4 << 30)
    code = f"""
import resource, pinrt
soft, hard = resource.getrlimit(resource.RLIMIT_AS)
used = int(open('/proc/self/statm').read().split()[0]) * resource.getpagesize()
resource.setrlimit(resource.RLIMIT_AS, (used + (512 << 20), hard))
try:
    pinrt.PinGrid({str(big)!r})
    print("opened")
except MemoryError as e:
    print("MemoryError:", e)
except pinrt.PinError as e:
    print("PinError:", e)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.startswith("MemoryError"), r.stdout + r.stderr


def test_embed_control_on_a_long_thin_array_names_no_unset_option(tmp_path):
    a = np.zeros((1, 1, 100_000), np.float32)
    a[0, 0, 40_000:60_000] = 1.0
    s = pinrt.bake(a, tmp_path / "o.pin", embed_control=True, **SMALL)
    assert s["file_bytes"] > 0
    PinGrid(tmp_path / "o.pin").verify()


def test_unreachable_target_error_is_refused_before_the_bake(tmp_path):
    a = np.random.default_rng(3).random((64, 64, 64), dtype=np.float32) * 40
    out = tmp_path / "o.pin"
    started = time.monotonic()
    # The pins-only choice (a grid option turns the default asset's rule off; that rule keeps
    # to its byte budget and says when the target is out of reach).
    with pytest.raises(ValueError, match="target_error 1e-9 cannot be met") as e:
        pinrt.bake(a, out, target_error=1e-9, pins_per_entry=1)
    assert "MiB" in str(e.value) and len(str(e.value)) < 400, str(e.value)
    assert time.monotonic() - started < 20
    assert not out.exists()


def test_a_control_grid_beyond_its_limit_is_refused_before_the_bake(tmp_path):
    out = tmp_path / "o.pin"
    started = time.monotonic()
    with pytest.raises(ValueError, match="control grid would have 256x256x256 bricks"):
        pinrt.bake("procedural:box", out, embed_control=1, **SMALL)
    assert time.monotonic() - started < 10
    assert not out.exists()
    pinrt.bake("procedural:box", out, embed_control=2, **SMALL)


def test_a_checked_open_catches_what_open_does_not(pin, tmp_path):
    data = bytearray(pin.read_bytes())
    g = PinGrid(pin)
    # A byte in the middle of the pin section (kind 2 in the section table): open maps it,
    # verify sums it.
    count = int.from_bytes(data[16:20], "little")
    table = int.from_bytes(data[24:32], "little")
    entries = [data[table + 32 * i : table + 32 * (i + 1)] for i in range(count)]
    pins = next(e for e in entries if int.from_bytes(e[0:4], "little") == 2)
    offset, length = int.from_bytes(pins[8:16], "little"), int.from_bytes(pins[16:24], "little")
    data[offset + length // 2] ^= 0x40
    bad = tmp_path / "bad.pin"
    bad.write_bytes(bytes(data))
    PinGrid(bad)  # opens: the pins are read lazily
    with pytest.raises(PinError, match="checksum"):
        PinGrid(bad, verify=True)
    with pytest.raises(PinError, match="checksum"):
        PinGrid.from_bytes(bytes(data), verify=True)
    assert PinGrid(pin, verify=True).info == g.info
