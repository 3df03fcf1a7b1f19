"""The pinrt wheel, installed in a fresh virtual environment, against the Rust tools.

scripts/python-test.sh builds the wheel and the two reference executables and sets:
  PINBAKE_EXE          the pinbake command (bakes must match it byte for byte)
  PINRT_REFERENCE_EXE  pinrt's query_reference example (the Rust sampler's values)
"""

from __future__ import annotations

import ast
import inspect
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import pinrt
from pinrt import PinError, PinGrid

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "data"
SEED = 11


def exe(var: str) -> str:
    path = os.environ.get(var)
    if not path or not Path(path).is_file():
        pytest.fail(f"{var} must name the built executable (scripts/python-test.sh sets it)")
    return path


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> Path:
    """The OpenVDB smoke baked small (12^3 cells) through the Python package."""
    out = tmp_path_factory.mktemp("smoke") / "smoke.pin"
    summary = pinrt.bake(DATA / "openvdb_smoke1.vdb", out, cells=12, step=0.02)
    assert summary["dims"] == [12, 12, 12]
    assert summary["source"] == "openvdb_smoke1.vdb"
    assert summary["file_bytes"] == out.stat().st_size
    assert summary["output"] == str(out)
    return out


def random_rays(grid: PinGrid, n: int, seed: int):
    """Rays from a box 1.5x the grid's world box towards random points inside it; a third end
    half way, the rest run to the exit."""
    box = grid.info["world_box"]
    lo, hi = np.array(box["min"]), np.array(box["max"])
    rng = np.random.default_rng(seed)
    c, h = (lo + hi) / 2, 0.75 * (hi - lo)
    o = c + h * rng.uniform(-1, 1, (n, 3))
    target = lo + (hi - lo) * rng.uniform(0, 1, (n, 3))
    d = target - o
    length = np.linalg.norm(d, axis=1)
    d /= length[:, None]
    t = np.where(np.arange(n) % 3 == 2, 0.5 * length, np.inf)
    return o.astype(np.float32), d.astype(np.float32), t.astype(np.float32)


def rust_reference(pin: Path, o, d, t, seed: int, tmp: Path, options: str | None = None):
    """The Rust sampler's transmittances and distances for the same rays, and its output
    (``options``: query_reference's ``SJ,DJ,STRIDE,start|middle,INSIDE[,NEAREST]``)."""
    n = len(o)
    rays = np.zeros((n, 8), dtype=np.float32)
    rays[:, 0:3], rays[:, 3], rays[:, 4:7] = o, t, d
    rays_file, out_file = tmp / "rays.bin", tmp / "out.bin"
    rays.astype("<f4").tofile(rays_file)
    run = subprocess.run(
        [exe("PINRT_REFERENCE_EXE"), str(pin), str(rays_file), str(seed), str(out_file)]
        + ([options] if options else []),
        capture_output=True, text=True, check=True,
    )
    values = np.fromfile(out_file, dtype="<f4")
    return values[:n], values[n:], run.stdout.strip()


def test_queries_equal_the_rust_sampler_bit_for_bit(smoke, tmp_path, capsys):
    grid = PinGrid(smoke)
    n = 1 << 18
    o, d, t = random_rays(grid, n, 1)
    want_t, want_d, rust_line = rust_reference(smoke, o, d, t, SEED, tmp_path)

    t0 = time.perf_counter()
    got_t = grid.transmittance(o, d, t, seed=SEED)
    t1 = time.perf_counter()
    got_d = grid.sample_distance(o, d, t, seed=SEED)
    t2 = time.perf_counter()

    assert got_t.dtype == np.float32 and got_t.shape == (n,)
    assert got_d.dtype == np.float32 and got_d.shape == (n,)
    np.testing.assert_array_equal(got_t.view(np.uint32), want_t.view(np.uint32))
    np.testing.assert_array_equal(got_d.view(np.uint32), want_d.view(np.uint32))
    hits = int(np.isfinite(got_d).sum())
    # The rays meet the medium: a comparison of misses alone would prove little.
    assert n // 10 < hits < n
    finite = np.isfinite(want_d)
    max_diff = max(
        float(np.max(np.abs(got_t - want_t))),
        float(np.max(np.abs(got_d[finite] - want_d[finite]))),
    )
    with capsys.disabled():
        print(
            f"\npython queries/s transmittance {n / (t1 - t0):.0f} distance {n / (t2 - t1):.0f}"
            f" (numpy arrays in and out)\n{rust_line}\n"
            f"max |python - rust| = {max_diff} over {n} rays ({hits} collisions)"
        )
    assert max_diff == 0.0


def test_seeds_and_first_index_follow_the_batch_contract(smoke):
    grid = PinGrid(smoke)
    o, d, t = random_rays(grid, 1000, 2)
    whole = grid.transmittance(o, d, t, seed=5)
    # Query i is seeded by (seed, first_index + i): a tail run alone reproduces the tail.
    tail = grid.transmittance(o[600:], d[600:], t[600:], seed=5, first_index=600)
    np.testing.assert_array_equal(tail, whole[600:])
    assert not np.array_equal(grid.transmittance(o, d, t, seed=6), whole)
    # Jitter changes the lookups, so it must change some numbers.
    thesis = grid.transmittance(o, d, t, seed=5, **pinrt.THESIS_LOOKUP)
    jittered = grid.transmittance(
        o, d, t, seed=5, **dict(pinrt.THESIS_LOOKUP, spatial_jitter=1.0, directional_jitter=1.0)
    )
    assert not np.array_equal(jittered, thesis)
    # A scalar t_max broadcasts; float64 and non-contiguous inputs are converted.
    a = grid.sample_distance(o.astype(np.float64)[::1], np.asfortranarray(d), np.inf, seed=3)
    b = grid.sample_distance(o, d, np.full(len(o), np.inf, np.float32), seed=3)
    np.testing.assert_array_equal(a, b)


def test_lookup_options_equal_the_rust_sampler_bit_for_bit(smoke, tmp_path):
    """pinrender render's lookup (jitter 1/1, middle, start inside) and a chained one, on rays
    of which half start inside the grid's box (where ``start_inside`` acts)."""
    grid = PinGrid(smoke)
    n = 20000
    o, d, t = random_rays(grid, n, 4)
    box = grid.info["world_box"]
    lo, hi = np.array(box["min"]), np.array(box["max"])
    inside = np.random.default_rng(5).uniform(0.1, 0.9, (n // 2, 3))
    o[: n // 2] = (lo + (hi - lo) * inside).astype(np.float32)
    render = dict(spatial_jitter=1.0, directional_jitter=1.0, chain_stride=32,
                  lookup_point="middle", start_inside=True, nearest_line=8)
    # The exported preset is the Rust constant pinrender render uses (read from it).
    assert pinrt.RENDER_LOOKUP == render
    render = pinrt.RENDER_LOOKUP
    thesis = pinrt.THESIS_LOOKUP
    assert thesis == dict(spatial_jitter=0.0, directional_jitter=0.0, chain_stride=0,
                          lookup_point="start", start_inside=False, nearest_line=0)
    plain = grid.transmittance(o, d, t, seed=SEED, **thesis)
    for kwargs, options in [
        (render, "1,1,0,middle,1,8"),
        (dict(thesis, spatial_jitter=0.5, chain_stride=4), "0.5,0,4,start,0"),
        (dict(thesis, directional_jitter=1.0, chain_stride=8, nearest_line=3), "0,1,8,start,0,3"),
    ]:
        want_t, want_d, _ = rust_reference(smoke, o, d, t, SEED, tmp_path, options)
        got_t = grid.transmittance(o, d, t, seed=SEED, **kwargs)
        got_d = grid.sample_distance(o, d, t, seed=SEED, **kwargs)
        np.testing.assert_array_equal(got_t.view(np.uint32), want_t.view(np.uint32))
        np.testing.assert_array_equal(got_d.view(np.uint32), want_d.view(np.uint32))
        # The options reach the sampler: the answers are not the thesis lookup's.
        assert not np.array_equal(got_t, plain)
    # start_inside changes only rays that start inside the box.
    base = dict(thesis, spatial_jitter=1.0, directional_jitter=1.0, lookup_point="middle")
    a = grid.transmittance(o, d, t, seed=SEED, **base)
    b = grid.transmittance(o, d, t, seed=SEED, **dict(base, start_inside=True))
    outside = np.any((o < lo) | (o > hi), axis=1)
    assert 1000 < outside.sum() < n // 2
    np.testing.assert_array_equal(a[outside], b[outside])
    assert not np.array_equal(a[~outside], b[~outside])
    with pytest.raises(ValueError, match="lookup_point"):
        grid.transmittance(o, d, t, lookup_point="end")
    with pytest.raises(ValueError, match="nearest_line is 65"):
        grid.transmittance(o, d, t, nearest_line=65)
    # The nearest-line search reaches the sampler (the smoke's grid is octahedral).
    assert grid.info["directions"]["kind"] == "octahedral"
    near = grid.transmittance(o, d, t, seed=SEED, **dict(render, nearest_line=0))
    assert not np.array_equal(near, grid.transmittance(o, d, t, seed=SEED, **render))


def test_query_defaults_are_the_render_lookup(smoke):
    """The queries' keyword defaults are ``RENDER_LOOKUP`` (``pinrt::SamplerOptions::RENDER``,
    the library's default), for both queries, and answer as that lookup does."""
    for query in (PinGrid.transmittance, PinGrid.sample_distance):
        params = inspect.signature(query).parameters
        defaults = {k: params[k].default for k in pinrt.RENDER_LOOKUP}
        assert defaults == pinrt.RENDER_LOOKUP, query.__name__
    grid = PinGrid(smoke)
    o, d, t = random_rays(grid, 5000, 6)
    np.testing.assert_array_equal(
        grid.sample_distance(o, d, t, seed=3),
        grid.sample_distance(o, d, t, seed=3, **pinrt.RENDER_LOOKUP),
    )
    assert not np.array_equal(
        grid.transmittance(o, d, t, seed=3),
        grid.transmittance(o, d, t, seed=3, **pinrt.THESIS_LOOKUP),
    )


def count_until(event: threading.Event) -> int:
    ticks = 0
    while not event.is_set():
        ticks += 1
    return ticks


def test_queries_release_the_gil(smoke):
    grid = PinGrid(smoke)
    o, d, t = random_rays(grid, 1 << 20, 3)
    grid.transmittance(o[:1000], d[:1000], t[:1000])  # warm the mapping
    # This thread's loop rate with nothing else wanting the interpreter.
    alone = threading.Event()
    timer = threading.Timer(0.3, alone.set)
    timer.start()
    rate_alone = count_until(alone) / 0.3

    done = threading.Event()
    spent = []

    def work():
        start = time.perf_counter()
        grid.transmittance(o, d, t, seed=1)
        grid.sample_distance(o, d, t, seed=1)
        spent.append(time.perf_counter() - start)
        done.set()

    th = threading.Thread(target=work)
    th.start()
    ticks = count_until(done)
    th.join()
    # With the GIL held by the queries this thread would only run in the switch-interval
    # slices before the Rust call (about 1% of its rate here); released, it keeps most of it.
    rate = ticks / spent[0]
    assert spent[0] > 0.05, "the workload is too small to tell"
    assert rate > 0.2 * rate_alone, f"loop rate {rate:.0f}/s against {rate_alone:.0f}/s alone: the GIL was held"


def test_python_bakes_equal_pinbake_bakes_byte_for_byte(smoke, tmp_path):
    cli = tmp_path / "cli.pin"
    subprocess.run(
        [exe("PINBAKE_EXE"), "bake", str(DATA / "openvdb_smoke1.vdb"), "-o", str(cli),
         "--cells", "12", "--step", "0.02", "-q"],
        check=True,
    )
    assert smoke.read_bytes() == cli.read_bytes()

    raw = DATA / "hydrogen_atom_128x128x128_uint8.raw"
    py = tmp_path / "h_py.pin"
    cli = tmp_path / "h_cli.pin"
    s = pinrt.bake(raw, py, cells=(8, 6, 7), density_scale=0.05, step=0.05,
                   directions="octahedral:4", pins_per_entry=2, seed=9, majorant=0)
    subprocess.run(
        [exe("PINBAKE_EXE"), "bake", str(raw), "-o", str(cli), "--cells", "8,6,7",
         "--density-scale", "0.05", "--step", "0.05", "--dirs", "octahedral:4",
         "--pins-per-entry", "2", "--seed", "9", "--majorant", "0", "-q"],
        check=True,
    )
    assert py.read_bytes() == cli.read_bytes()
    assert s["directions"] == {"kind": "octahedral", "n": 4}
    assert s["pins_per_entry"] == 2 and s["seed"] == 9

    # The baked control of residual tracking (pinrender's pinres), as --embed-control.
    py = tmp_path / "h_py_control.pin"
    cli = tmp_path / "h_cli_control.pin"
    pinrt.bake(raw, py, cells=4, density_scale=0.05, step=0.05, embed_control=8)
    subprocess.run(
        [exe("PINBAKE_EXE"), "bake", str(raw), "-o", str(cli), "--cells", "4",
         "--density-scale", "0.05", "--step", "0.05", "--embed-control", "8", "-q"],
        check=True,
    )
    assert py.read_bytes() == cli.read_bytes()
    plain = tmp_path / "h_py_plain.pin"
    pinrt.bake(raw, plain, cells=4, density_scale=0.05, step=0.05)
    assert plain.stat().st_size < py.stat().st_size
    # True and "auto" are the CLI's --embed-control without a value; False is none.
    auto_cli = tmp_path / "h_cli_auto.pin"
    subprocess.run(
        [exe("PINBAKE_EXE"), "bake", str(raw), "-o", str(auto_cli), "--cells", "4",
         "--density-scale", "0.05", "--step", "0.05", "--embed-control", "-q"],
        check=True,
    )
    for flag in (True, "auto"):
        auto_py = tmp_path / f"h_py_auto_{flag}.pin"
        pinrt.bake(raw, auto_py, cells=4, density_scale=0.05, step=0.05, embed_control=flag)
        assert auto_py.read_bytes() == auto_cli.read_bytes()
    none_py = tmp_path / "h_py_none.pin"
    pinrt.bake(raw, none_py, cells=4, density_scale=0.05, step=0.05, embed_control=False)
    assert none_py.read_bytes() == plain.read_bytes()

    # The embedded density, dense or sparse, as --embed-density's text.
    for flag, arg in (("sparse", "sparse"), ("sparse:16", "sparse:16"), ("8", 8)):
        py = tmp_path / f"h_py_density_{flag}.pin"
        cli = tmp_path / f"h_cli_density_{flag}.pin"
        s = pinrt.bake(raw, py, cells=4, density_scale=0.05, step=0.05, embed_density=arg)
        subprocess.run(
            [exe("PINBAKE_EXE"), "bake", str(raw), "-o", str(cli), "--cells", "4",
             "--density-scale", "0.05", "--step", "0.05", "--embed-density", flag, "-q"],
            check=True,
        )
        assert py.read_bytes() == cli.read_bytes(), flag
        assert py.stat().st_size > plain.stat().st_size, flag
    with pytest.raises(ValueError, match="embed_density"):
        pinrt.bake(raw, tmp_path / "never.pin", cells=4, embed_density="sparse:0")


def test_gpu_bakes_equal_pinbake_gpu_bakes_byte_for_byte(tmp_path):
    # backend="gpu" is --backend gpu: on one device the same bytes as the command, with the
    # GPU's breakdown in the summary; the CPU's summary has none.
    raw = DATA / "hydrogen_atom_128x128x128_uint8.raw"
    opts = dict(cells=(6, 5, 4), density_scale=0.05, step=0.05, directions="octahedral:4")
    py = tmp_path / "gpu_py.pin"
    s = pinrt.bake(raw, py, backend="gpu", **opts)
    cli = tmp_path / "gpu_cli.pin"
    subprocess.run(
        [exe("PINBAKE_EXE"), "bake", str(raw), "-o", str(cli), "--cells", "6,5,4",
         "--density-scale", "0.05", "--step", "0.05", "--dirs", "octahedral:4",
         "--backend", "gpu", "-q"],
        check=True,
    )
    assert py.read_bytes() == cli.read_bytes()
    assert s["gpu"]["dispatches"] >= 1 and s["gpu"]["adapter"]
    cpu = tmp_path / "cpu_py.pin"
    assert "gpu" not in pinrt.bake(raw, cpu, **opts)
    # The same layout: only entries may differ (within docs/gpu.md's bound).
    assert cpu.stat().st_size == py.stat().st_size
    with pytest.raises(ValueError, match="backend 'tpu'"):
        pinrt.bake(raw, tmp_path / "never.pin", backend="tpu", **opts)
    assert not (tmp_path / "never.pin").exists()


def test_a_bake_with_no_options_is_pinbakes_default_asset(tmp_path):
    """No grid options: the default asset, as `pinbake bake` with no flags writes it, byte
    for byte, no larger than its input plus 64 KiB; `max_bytes` bounds it."""
    vdb = DATA / "gaffer_sphere_density.vdb"
    py, cli = tmp_path / "py.pin", tmp_path / "cli.pin"
    s = pinrt.bake(vdb, py)
    subprocess.run([exe("PINBAKE_EXE"), "bake", str(vdb), "-o", str(cli), "-q"], check=True)
    assert py.read_bytes() == cli.read_bytes()
    assert s["file_bytes"] <= vdb.stat().st_size + (64 << 10)
    assert s["choice"]["asset"]["chosen"]["representation"] in ("dense", "sparse")
    # An array: its float32 bytes are the budget's base.
    x, y, z = np.meshgrid(*(np.linspace(-1, 1, n) for n in (20, 18, 22)), indexing="ij")
    a = (30 * np.exp(-(x * x + y * y + z * z) / 0.2)).astype(np.float32)
    s = pinrt.bake(a, tmp_path / "a.pin", spacing=0.05)
    assert s["choice"]["asset"]["max_bytes"] == a.nbytes + (64 << 10)
    assert s["file_bytes"] <= a.nbytes + (64 << 10)
    s = pinrt.bake(a, tmp_path / "b.pin", spacing=0.05, max_bytes=48 << 10)
    assert s["file_bytes"] <= 48 << 10
    with pytest.raises(ValueError, match="max-bytes"):
        pinrt.bake(a, tmp_path / "c.pin", spacing=0.05, max_bytes=1024)


def test_arrays_bake_like_the_same_voxels_in_a_raw_file(tmp_path):
    # A blob in a 20x16x12 grid indexed [x, y, z] and stored in Fortran order, to show that
    # indexing, not memory layout, defines the axes.
    x, y, z = np.meshgrid(np.arange(20), np.arange(16), np.arange(12), indexing="ij")
    vol = np.exp(-((x - 6.0) ** 2 / 20 + (y - 9.0) ** 2 / 10 + (z - 4.0) ** 2 / 8)) * 3.0
    vol = np.asfortranarray(vol)
    spacing, origin = (0.5, 0.25, 1.0), (-1.0, 2.0, 0.5)
    arr_pin = tmp_path / "arr.pin"
    s = pinrt.bake(vol, arr_pin, spacing=spacing, origin=origin, cells=6, step=0.05)
    assert s["source"] == "<array>"
    assert s["source_box"]["min"] == list(origin)
    np.testing.assert_allclose(s["source_box"]["max"], [-1.0 + 10.0, 2.0 + 4.0, 0.5 + 12.0])

    # The same voxels as a raw f32 file (x fastest) baked by the same code path.
    raw = tmp_path / "blob_20x16x12_f32.raw"
    vol.astype("<f4").transpose(2, 1, 0).tofile(raw)
    raw_pin = tmp_path / "raw.pin"
    pinrt.bake(raw, raw_pin, spacing=spacing, origin=origin, cells=6, step=0.05)
    a, b = PinGrid(arr_pin), PinGrid(raw_pin)
    o, d, t = random_rays(a, 20000, 4)
    np.testing.assert_array_equal(a.transmittance(o, d, t, seed=2), b.transmittance(o, d, t, seed=2))
    np.testing.assert_array_equal(a.sample_distance(o, d, t, seed=2), b.sample_distance(o, d, t, seed=2))
    # ...while the volume mirrored along x is a different medium (the test can fail).
    wrong = tmp_path / "wrong.pin"
    pinrt.bake(vol[::-1], wrong, spacing=spacing, origin=origin, cells=6, step=0.05)
    assert not np.array_equal(PinGrid(wrong).transmittance(o, d, t, seed=2), a.transmittance(o, d, t, seed=2))


def test_errors_are_exceptions_with_the_one_line_messages(tmp_path, smoke):
    missing = tmp_path / "missing.pin"
    with pytest.raises(PinError, match=f"^{missing}: No such file or directory"):
        PinGrid(missing)
    short = tmp_path / "short.pin"
    short.write_bytes(smoke.read_bytes()[:1000])
    with pytest.raises(PinError, match=f"^{short}: ") as e:
        PinGrid(short)
    assert "\n" not in str(e.value)
    with pytest.raises(PinError, match="^<memory>: "):
        PinGrid.from_bytes(b"not a pin file")
    with pytest.raises(PinError, match="missing.vdb"):
        pinrt.bake(tmp_path / "missing.vdb", tmp_path / "x.pin")
    with pytest.raises(PinError, match="^array: "):
        pinrt.bake(-np.ones((4, 4, 4)), tmp_path / "x.pin")
    with pytest.raises(ValueError, match="3-D"):
        pinrt.bake(np.ones((4, 4)), tmp_path / "x.pin")
    with pytest.raises(ValueError, match="floats"):
        pinrt.bake(np.ones((4, 4, 4), dtype=np.int32), tmp_path / "x.pin")
    with pytest.raises(ValueError, match="directions 'polar:16'"):
        pinrt.bake(np.ones((4, 4, 4)), tmp_path / "x.pin", directions="polar:16")
    grid = PinGrid(smoke)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        grid.transmittance(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="t_max"):
        grid.transmittance(np.zeros((5, 3)), np.ones((5, 3)), np.ones(4))
    with pytest.raises(ValueError, match="spatial_jitter"):
        grid.transmittance(np.zeros((5, 3)), np.ones((5, 3)), spatial_jitter=-1.0)
    # Invalid rays are answered, not raised: transmittance 1, no collision.
    o = np.array([[np.nan, 0, 0], [0, 0, 0]], np.float32)
    d = np.array([[1, 0, 0], [0, 0, 0]], np.float32)
    np.testing.assert_array_equal(grid.transmittance(o, d), [1.0, 1.0])
    np.testing.assert_array_equal(grid.sample_distance(o, d), [np.inf, np.inf])
    assert len(grid.transmittance(np.zeros((0, 3)), np.zeros((0, 3)))) == 0


def test_info_and_verify(smoke):
    grid = PinGrid(smoke)
    info = grid.info
    assert info["dims"] == [12, 12, 12]
    # Chosen from the volume as `pinbake bake` chooses (the byte-for-byte test compares them).
    assert info["directions"]["kind"] == "octahedral"
    assert info["mapped"] is True and info["file_bytes"] == smoke.stat().st_size
    grid.verify()
    copy = PinGrid.from_bytes(smoke.read_bytes())
    assert copy.info["mapped"] is False
    damaged = bytearray(smoke.read_bytes())
    damaged[-100] ^= 0xFF
    with pytest.raises(PinError):
        PinGrid.from_bytes(bytes(damaged)).verify()


def test_stub_matches_the_compiled_module():
    stub = Path(pinrt.__file__).with_name("_native.pyi")
    tree = ast.parse(stub.read_text())
    declared = {
        n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))
    } | {
        n.target.id for n in tree.body
        if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
    }
    public = {n for n in dir(pinrt._native) if not n.startswith("_")}
    assert declared == public
    methods = {
        n.name for c in tree.body if isinstance(c, ast.ClassDef) and c.name == "PinGrid"
        for n in c.body if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")
    }
    assert methods == {n for n in dir(pinrt._native.PinGrid) if not n.startswith("_")}
    assert (Path(pinrt.__file__).parent / "py.typed").is_file()
