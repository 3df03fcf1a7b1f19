"""pinrt: bake volumes into pin grids and sample them from Python.

The compiled core is the same Rust code as the ``pinbake`` command and the ``pinrt`` runtime:

* :func:`bake` bakes a 3-D NumPy float array (with ``spacing`` and ``origin``) or any file
  ``pinbake bake`` reads (``.vdb``, ``.nvdb``, ``.raw``, ``procedural:SPEC``) into a pin file and returns
  the summary that ``pinbake bake --json`` prints, as a dict.
* :class:`PinGrid` opens a pin file (memory-mapped) and answers batched transmittance and
  free-flight distance queries over (N, 3) arrays of origins and directions, with the GIL
  released. Query ``i`` draws from the generator seeded by ``(seed, first_index + i)``: the
  numbers equal the Rust sampler's (and the C ABI's, and the GPU shader's) bit for bit.

Failures raise :class:`PinError` with the library's one-line message (naming the file);
malformed arguments raise ``ValueError`` (non-numeric arrays, ``t_max=None``, options out of
range or not applying to the input); a buffer that cannot be allocated, or a bake over the
memory budget, raises ``MemoryError``. ``pinrt._native`` is the compiled layer under this
module: it accepts only C-contiguous float32 arrays and refuses others; call this module.

A single transmittance estimate is ``t_min ** n`` for a whole number ``n``: it is right on
average, not per call. Average many estimates (different seeds or query indices) when one
ray's value matters.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import sysconfig
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Optional, Sequence, Tuple, Union

from pinrt import _native
from pinrt._native import PinError

if TYPE_CHECKING:  # NumPy is imported lazily: the OpenVDB worker must not load it.
    import numpy as np
    import numpy.typing as npt

__all__ = ["PinError", "PinGrid", "RENDER_LOOKUP", "THESIS_LOOKUP", "bake"]

#: The default lookup of the queries, the one ``pinrender render`` uses, measured the least
#: biased on volumes nobody tuned for (``pinrt::SamplerOptions::RENDER``; docs/sampling.md
#: sections 11-15). The queries' keyword defaults are these values.
RENDER_LOOKUP: Dict[str, Any] = dict(_native.RENDER_LOOKUP)
#: The thesis' lookup (``pinrt::SamplerOptions::THESIS``: no jitter, one lookup at the
#: segment start): ``grid.transmittance(o, d, t, **pinrt.THESIS_LOOKUP)``.
THESIS_LOOKUP: Dict[str, Any] = dict(_native.THESIS_LOOKUP)
__version__ = "0.1.0"

_WORKER = "pinrt-vdb-worker"


def _worker_path() -> Optional[str]:
    """The installed ``pinrt-vdb-worker`` script: beside the interpreter (virtual
    environments), in the scheme's scripts directory, or on ``PATH``."""
    for d in (Path(sys.executable).parent, Path(sysconfig.get_path("scripts"))):
        p = d / _WORKER
        if p.is_file() and os.access(p, os.X_OK):
            return str(p)
    return shutil.which(_WORKER)


_U32 = (1 << 32) - 1
_U64 = (1 << 64) - 1


def _shown(v: Any) -> str:
    """A value for a message: huge integers by their size, not their 300 digits."""
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 10**12:
        return f"{'-' if v < 0 else ''}a {abs(v).bit_length()}-bit integer"
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _int(name: str, v: Any, lo: int, hi: int) -> int:
    """``v`` as an integer in ``lo..=hi``, else ``ValueError`` naming ``name`` (never the
    ``OverflowError`` or ``TypeError`` of the conversion to the native type)."""
    import numbers

    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise ValueError(f"{name} must be an integer, got {_shown(v)}")
    i = int(v)
    if not lo <= i <= hi:
        raise ValueError(f"{name} is {_shown(i)}; it must be in {lo}..={hi}")
    return i


def _opt_int(name: str, v: Any, lo: int, hi: int) -> Optional[int]:
    return None if v is None else _int(name, v, lo, hi)


def _triple(name: str, v: Any, lo: int = 0, hi: int = _U32) -> Tuple[int, int, int]:
    import numbers

    if isinstance(v, numbers.Integral) and not isinstance(v, bool):
        i = _int(name, v, lo, hi)
        return (i, i, i)
    try:
        t = tuple(v)
    except TypeError:
        raise ValueError(f"{name} must be one integer or three, got {_shown(v)}") from None
    if len(t) != 3:
        raise ValueError(f"{name} must be one integer or three, got {_shown(v)}")
    a, b, c = (_int(name, x, lo, hi) for x in t)
    return (a, b, c)


def _embed_density(v: Any) -> Union[str, Tuple[int, int, int], None]:
    """``embed_density``: None, ``--embed-density``'s text (``"sparse"``, ``"sparse:N"``,
    ``"sparse:X,Y,Z"``), or dense voxels per axis (N or (X, Y, Z))."""
    if v is None or isinstance(v, str):
        return v
    return _triple("embed_density", v)


def _embed_control(v: Any) -> Union[bool, int, str, None]:
    """``embed_control``: None, a bool, ``"auto"`` or a brick edge of 1..=64 voxels; anything
    else (-1, 2**40, 1.5) is a ``ValueError``."""
    if v is None or isinstance(v, (bool, str)):
        return v
    return _int("embed_control", v, 1, 64)


def _floats3(name: str, v: Union[float, Sequence[float], None]) -> Optional[Tuple[float, float, float]]:
    if v is None:
        return None
    if isinstance(v, (int, float)):
        return (float(v),) * 3  # type: ignore[return-value]
    t = tuple(float(x) for x in v)
    if len(t) != 3:
        raise ValueError(f"{name} must be one number or three, got {v!r}")
    return (t[0], t[1], t[2])


def bake(
    array_or_path: Union["npt.ArrayLike", str, "os.PathLike[str]"],
    output: Union[str, "os.PathLike[str]"],
    *,
    spacing: Union[float, Sequence[float], None] = None,
    origin: Union[float, Sequence[float], None] = None,
    cells: Union[int, Sequence[int], None] = None,
    directions: Optional[str] = None,
    pins_per_entry: Optional[int] = None,
    target_error: Optional[float] = None,
    step: float = 0.01,
    seed: int = 0,
    crop: bool = True,
    center_pins: bool = True,
    majorant: Union[int, Sequence[int]] = 16,
    embed_density: Union[int, Sequence[int], str, None] = None,
    embed_control: Union[int, bool, str, None] = None,
    density_scale: float = 1.0,
    threads: Optional[int] = None,
    max_memory: Optional[int] = None,
    grid: Optional[str] = None,
    levelset_to_fog: bool = False,
    dims: Union[int, Sequence[int], None] = None,
    voxel_type: Optional[str] = None,
    endian: Optional[str] = None,
    clamp_negative: bool = False,
    nan_as_zero: bool = False,
    backend: str = "cpu",
    max_bytes: Optional[int] = None,
) -> Dict[str, Any]:
    """Bakes a volume into the pin file ``output`` and returns the ``pinbake bake --json``
    summary as a dict.

    ``array_or_path`` is a 3-D NumPy float array indexed ``[x, y, z]`` (any memory order,
    strided or broadcast; values finite and >= 0; ``spacing`` is the world size of a voxel and
    ``origin`` the world position of the grid box's minimum corner), or a path that ``pinbake bake`` reads: an
    OpenVDB fog volume (``grid``, ``levelset_to_fog``), a raw file (``dims``, ``voxel_type``
    u8/u16/f16/f32/f64, ``endian``, ``spacing``, ``origin``, ``clamp_negative``,
    ``nan_as_zero``; dims and type may come from a ``NAME_XxYxZ_TYPE.raw`` file name), or
    ``"procedural:SPEC"``.

    With none of ``cells``, ``directions``, ``pins_per_entry`` and ``embed_density`` given,
    the file is ``pinbake bake``'s default asset: the smallest file whose image from the file
    alone is predicted within ``target_error`` (default 0.01) 8x8-block error of the
    full-resolution volume, in at most ``max_bytes`` (``--max-bytes``; default the input
    file's size, or the array's float32 bytes, plus 64 KiB): for a voxel input, its density
    box-filtered to the coarsest resolution that meets the target, with a small pin grid
    (``docs/scale.md``, "The default asset"); the summary's ``choice.asset`` says what was
    chosen and the predicted error of each alternative weighed.

    The other options are ``pinbake bake``'s flags, with its defaults: ``cells`` (N or
    (X, Y, Z)), ``directions`` (``octahedral:N`` or ``polar:PHIxTHETA``) and
    ``pins_per_entry``, each chosen from the volume when left out as ``pinbake bake`` does
    (``docs/evaluation.md``, "Bias against bytes"; ``target_error`` is ``--target-error``),
    ``step``
    (relative to the longest box edge), ``seed``, ``crop`` (False is ``--no-crop``),
    ``center_pins`` (False is ``--jitter-pins``), ``majorant`` (0 leaves it out), ``embed_density`` (N or (X, Y, Z) voxels of a
    dense f16 copy; counts at the source's resolution, or a whole F of it, hold its voxels as
    ``"voxels:F"`` does, or ``"sparse"``, ``"sparse:N"``, ``"sparse:X,Y,Z"``: f16 bricks where the
    density is non-zero, or ``"voxels:F"``, ``"sparse-voxels:F"``: the source's voxels, each
    F^3 averaged into one, as ``--embed-density``), ``embed_control``
    (``--embed-control [EDGE]``: residual tracking's control per brick of EDGE voxels, 1..=64,
    or ``True``/``"auto"`` for the default edge, which grows with the volume's resolution;
    for ``pinrender``'s ``pinres``), ``density_scale``
    ``threads`` and ``max_memory`` (bytes; ``--max-memory``, default half of the physical
    memory). ``backend`` is ``"cpu"`` or ``"gpu"`` (``--backend``: the pins' entries from a wgpu
    compute pass; the file's layout and sections are the same, its entries within the bound
    ``docs/gpu.md`` states; no adapter raises :class:`PinError`; the summary then has a ``gpu``
    object with where the time went). A bake is deterministic: the same input and options
    give the same bytes as the ``pinbake`` command with the same backend.

    The bake runs through the same Rust code as ``pinbake bake`` (``pinbake::plan``), with
    its rules: ``output`` must be a new path or a regular file that is not the input (a
    symlink to a file replaces the file and keeps the link; directories, devices, FIFOs and
    dangling symlinks are refused) and is written atomically; options outside their ranges
    (``step`` in [1e-5, 1], ``spacing`` in [1e-9, 1e9], ``origin`` within 1e12, integers
    outside their type such as ``seed=-1``, ...) and options that do not apply to the input
    (``dims`` for an array, ``grid`` for a raw file) raise ``ValueError``; a bake over the
    memory budget, or a copy that cannot be allocated, raises ``MemoryError``; a bad input
    raises :class:`PinError`.

    Memory: a float32 or float64 array is copied once, by the extension, after that copy (and
    the array) is counted against ``max_memory``; other float dtypes are converted here after
    the same check, which counts that conversion too. A masked array with masked voxels raises
    ``ValueError`` (the mask would be ignored); one with nothing masked bakes its data.

    Placement: the grid's box and transform must be finite, invertible and within what f32
    queries represent (corners within 1e12, edges at least 1e-9 and 1e-5 of the largest
    coordinate), the rule every reader applies at open: ``ValueError`` for ``spacing`` and
    ``origin``, :class:`PinError` for a file or ``procedural:`` spec.

    Size: a ``target_error`` whose chosen bake would exceed 256 MiB of pins, and an
    ``embed_control`` grid of more than 2^21 bricks (an analytic field counts 256 voxels along
    its longest axis), raise ``ValueError`` before the bake starts, naming the limit.

    Ctrl-C (``KeyboardInterrupt``) stops a running bake within a second and leaves no output
    and no temp file.
    """
    kwargs: Dict[str, Any] = dict(
        cells=None if cells is None else _triple("cells", cells, 1),
        directions=directions,
        pins_per_entry=_opt_int("pins_per_entry", pins_per_entry, 0, _U32),
        target_error=target_error,
        step=step,
        seed=_int("seed", seed, 0, _U64),
        crop=crop,
        center_pins=center_pins,
        majorant=_triple("majorant", majorant),
        embed_density=_embed_density(embed_density),
        embed_control=_embed_control(embed_control),
        density_scale=density_scale,
        threads=_opt_int("threads", threads, 1, _U32),
        max_memory=_opt_int("max_memory", max_memory, 1, _U64),
        max_bytes=_opt_int("max_bytes", max_bytes, 1, _U64),
        spacing=_floats3("spacing", spacing),
        origin=_floats3("origin", origin),
        # Passed for every input: the options that do not apply to it are refused there.
        grid=grid,
        levelset_to_fog=levelset_to_fog,
        dims=None if dims is None else _triple("dims", dims, 1),
        voxel_type=voxel_type,
        endian=endian,
        clamp_negative=clamp_negative,
        nan_as_zero=nan_as_zero,
        backend=backend,
    )
    out = os.fspath(output)
    if isinstance(array_or_path, (str, os.PathLike)):
        path = os.fspath(array_or_path)
        if path.lower().endswith(".vdb"):
            worker = _worker_path()
            if worker is None:
                raise PinError(f"{path}: the {_WORKER} script is not installed (reinstall pinrt)")
            kwargs["vdb_worker"] = worker
        return json.loads(_native.bake(path, out, **kwargs))

    import numpy as np

    if isinstance(array_or_path, np.ma.MaskedArray):
        # np.asarray would drop the mask and bake the hidden values.
        if np.ma.getmask(array_or_path) is not np.ma.nomask and np.ma.getmask(array_or_path).any():
            raise ValueError(
                "the volume array is a masked array with masked voxels: the mask would be "
                "ignored; fill them first (a.filled(0.0)) or pass a.data"
            )
        array_or_path = np.ma.getdata(array_or_path)
    a = np.asarray(array_or_path)
    if a.ndim != 3:
        raise ValueError(f"the volume array must be 3-D, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"the volume array must hold floats, got dtype {a.dtype}")
    held = 0
    if a.dtype not in (np.float32, np.float64):
        # float16, longdouble: converted here, a copy that lives through the bake and is
        # counted against max_memory beside the bake's own copy. Its size is checked first.
        held = a.size * 4
        _native.check_array_memory(a.shape, held, kwargs["max_memory"])
        a = a.astype(np.float32)
    # Any memory order (C, Fortran, strided, broadcast): the extension copies the [x, y, z]
    # voxels x-fastest into the bake's grid, once, after counting that copy against max_memory.
    return json.loads(_native.bake("<array>", out, data=a, held_bytes=held, **kwargs))


def _numeric(name: str, value: "npt.ArrayLike") -> "np.ndarray":
    """``value`` as an array of integers or floats: datetimes, strings, booleans, objects and
    structured records are refused instead of being converted silently."""
    import numpy as np

    if value is None:
        raise ValueError(f"{name} is None; pass numbers (t_max=math.inf runs to the box's exit)")
    a = np.asarray(value)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must hold integers or floats, got dtype {a.dtype}")
    return a


def _rays(
    origins: "npt.ArrayLike", directions: "npt.ArrayLike", t_max: "npt.ArrayLike"
) -> Tuple["np.ndarray", "np.ndarray", "np.ndarray"]:
    import numpy as np

    o = np.ascontiguousarray(_numeric("origins", origins), dtype=np.float32)
    d = np.ascontiguousarray(_numeric("directions", directions), dtype=np.float32)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins must have shape (N, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    t = np.asarray(_numeric("t_max", t_max), dtype=np.float32)
    if t.ndim > 1 or (t.ndim == 1 and t.shape[0] != o.shape[0]):
        raise ValueError(f"t_max must be a number or shape ({o.shape[0]},), got {t.shape}")
    t = np.ascontiguousarray(np.broadcast_to(t, (o.shape[0],)))
    return o, d, t


def _query_ints(seed: Any, first_index: Any, chain_stride: Any, nearest_line: Any) -> Tuple[int, int, int, int]:
    """The integer query options, each a 32-bit unsigned integer (``ValueError`` otherwise)."""
    return (
        _int("seed", seed, 0, _U32),
        _int("first_index", first_index, 0, _U32),
        _int("chain_stride", chain_stride, 0, _U32),
        _int("nearest_line", nearest_line, 0, _U32),
    )


class PinGrid:
    """An open pin grid. ``PinGrid(path)`` memory-maps the file (O(1), no copy);
    :meth:`from_bytes` copies a file's bytes. Safe to query from many threads at once.

    Only regular files are opened (a FIFO or a device raises :class:`PinError` at once, it
    is never waited on). A mapped file must not be truncated or rewritten in place while it
    is open: touching a vanished page raises SIGBUS, which kills the interpreter. Replace pin
    files atomically (write a new file, then rename it over the old one, as ``pinbake`` and
    :func:`bake` do): the mapping keeps the old file alive. Where that cannot be ruled out,
    use ``PinGrid.from_bytes(open(path, "rb").read())``.

    What opening checks, in time independent of the file's size (the pins are read lazily,
    as queries reach them): the header, the section table and the grid description and their
    checksums, every count against the file's length, and the placement (box and
    ``local_to_world`` finite, invertible and within what f32 queries represent, the rule
    :func:`bake` applies). The pin section and the cell index are not checksummed at open: a
    damaged byte there changes query results silently. :meth:`verify` adds every section's
    checksum and every stored value (linear in the file size). Pipelines that take files
    from elsewhere open them with ``verify=True``, which runs :meth:`verify` before the grid
    is returned."""

    __slots__ = ("_g",)

    def __init__(self, path: Union[str, "os.PathLike[str]"], *, verify: bool = False) -> None:
        """Opens (memory-maps) the pin file ``path``; with ``verify=True`` also checks every
        checksum and value first (:meth:`verify`). Raises :class:`PinError` for a file that
        is not a valid pin file, ``MemoryError`` when it cannot be mapped (out of memory or
        address space)."""
        self._g = _native.PinGrid(os.fspath(path))
        if verify:
            self._g.verify()

    @classmethod
    def from_bytes(cls, data: bytes, *, verify: bool = False) -> "PinGrid":
        """A grid from the bytes of a pin file (copied), checked as ``PinGrid(path)``
        checks a file, and with ``verify=True`` as :meth:`verify` does."""
        g = cls.__new__(cls)
        g._g = _native.PinGrid.from_bytes(data)
        if verify:
            g._g.verify()
        return g

    @property
    def info(self) -> Dict[str, Any]:
        """The grid description: dims, directions, pins, boxes, placement, bake settings."""
        return json.loads(self._g.info_json())

    def verify(self) -> None:
        """Checks what opening does not: every section's checksum (pins and cell index
        included) and every stored value, linear in the file size; raises :class:`PinError`
        naming the file and the damage."""
        self._g.verify()

    def transmittance(
        self,
        origins: "npt.ArrayLike",
        directions: "npt.ArrayLike",
        t_max: "npt.ArrayLike" = math.inf,
        *,
        seed: int = 0,
        first_index: int = 0,
        spatial_jitter: float = 1.0,
        directional_jitter: float = 1.0,
        chain_stride: int = 32,
        lookup_point: str = "middle",
        start_inside: bool = True,
        nearest_line: int = 8,
    ) -> "np.ndarray":
        """Transmittance estimates over ``[0, t_max]`` of N rays (``t_max`` a number or N
        numbers; ``inf`` runs to the grid box's exit). Directions need not be unit length:
        distances are in units of the ray parameter. Returns float32 of shape (N,).

        The lookup options are ``pinrt::SamplerOptions``'s (docs/sampling.md sections 12-15):
        ``spatial_jitter`` and ``directional_jitter`` in cells, ``chain_stride`` in intervals
        (0: one lookup per query), ``lookup_point`` ``"start"`` or ``"middle"`` of the segment,
        ``start_inside`` (a ray starting inside the box is looked up at its start, without
        spatial jitter), ``nearest_line`` (0-64: read the cell whose pin line passes nearest
        the lookup point, searching that many one-cell steps each side; replaces the spatial
        jitter; octahedral grids). The defaults are the library's default lookup,
        ``RENDER_LOOKUP`` (``pinrender render``'s, the least biased); the thesis' lookup is
        ``**THESIS_LOOKUP`` (no jitter, one lookup at the segment start)."""
        o, d, t = _rays(origins, directions, t_max)
        seed, first_index, chain_stride, nearest_line = _query_ints(
            seed, first_index, chain_stride, nearest_line
        )
        return self._g.transmittance(
            o, d, t, seed, first_index, spatial_jitter, directional_jitter,
            chain_stride, lookup_point, start_inside, nearest_line,
        )

    def sample_distance(
        self,
        origins: "npt.ArrayLike",
        directions: "npt.ArrayLike",
        t_max: "npt.ArrayLike" = math.inf,
        *,
        seed: int = 0,
        first_index: int = 0,
        spatial_jitter: float = 1.0,
        directional_jitter: float = 1.0,
        chain_stride: int = 32,
        lookup_point: str = "middle",
        start_inside: bool = True,
        nearest_line: int = 8,
    ) -> "np.ndarray":
        """Sampled free-flight distances in ``[0, t_max]`` of N rays, ``inf`` where a ray
        passes without a collision. Returns float32 of shape (N,). The lookup options are
        ``transmittance``'s."""
        o, d, t = _rays(origins, directions, t_max)
        seed, first_index, chain_stride, nearest_line = _query_ints(
            seed, first_index, chain_stride, nearest_line
        )
        return self._g.sample_distance(
            o, d, t, seed, first_index, spatial_jitter, directional_jitter,
            chain_stride, lookup_point, start_inside, nearest_line,
        )
