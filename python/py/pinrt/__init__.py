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


def _triple(name: str, v: Union[int, Sequence[int]]) -> Tuple[int, int, int]:
    if isinstance(v, int):
        return (v, v, v)
    t = tuple(int(x) for x in v)
    if len(t) != 3:
        raise ValueError(f"{name} must be one integer or three, got {v!r}")
    return (t[0], t[1], t[2])


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
    embed_density: Union[int, Sequence[int], None] = None,
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
) -> Dict[str, Any]:
    """Bakes a volume into the pin file ``output`` and returns the ``pinbake bake --json``
    summary as a dict.

    ``array_or_path`` is a 3-D NumPy float array indexed ``[x, y, z]`` (any memory order;
    values finite and >= 0; ``spacing`` is the world size of a voxel and ``origin`` the world
    position of the grid box's minimum corner), or a path that ``pinbake bake`` reads: an
    OpenVDB fog volume (``grid``, ``levelset_to_fog``), a raw file (``dims``, ``voxel_type``
    u8/u16/f16/f32/f64, ``endian``, ``spacing``, ``origin``, ``clamp_negative``,
    ``nan_as_zero``; dims and type may come from a ``NAME_XxYxZ_TYPE.raw`` file name), or
    ``"procedural:SPEC"``.

    The other options are ``pinbake bake``'s flags, with its defaults: ``cells`` (N or
    (X, Y, Z)), ``directions`` (``octahedral:N`` or ``polar:PHIxTHETA``) and
    ``pins_per_entry``, each chosen from the volume when left out as ``pinbake bake`` does
    (``docs/evaluation.md``, "Bias against bytes"; ``target_error`` is ``--target-error``),
    ``step``
    (relative to the longest box edge), ``seed``, ``crop`` (False is ``--no-crop``),
    ``center_pins`` (False is ``--jitter-pins``), ``majorant`` (0 leaves it out), ``embed_density``, ``embed_control``
    (``--embed-control [EDGE]``: residual tracking's control per brick of EDGE voxels, 1..=64,
    or ``True``/``"auto"`` for the default edge, which grows with the volume's resolution;
    for ``pinrender``'s ``pinres``), ``density_scale``
    ``threads`` and ``max_memory`` (bytes; ``--max-memory``, default half of the physical
    memory). A bake is deterministic: the same input and options give the same bytes as the
    ``pinbake`` command.

    The bake runs through the same Rust code as ``pinbake bake`` (``pinbake::plan``), with
    its rules: ``output`` must be a new path or a regular file that is not the input (a
    symlink to a file replaces the file and keeps the link; directories, devices, FIFOs and
    dangling symlinks are refused) and is written atomically; options outside their ranges
    (``step`` in [1e-5, 1], ``spacing`` in [1e-9, 1e9], ``origin`` within 1e12, ...) and
    options that do not apply to the input (``dims`` for an array, ``grid`` for a raw file)
    raise ``ValueError``; a bake over the memory budget, or a copy that cannot be allocated,
    raises ``MemoryError``; a bad input raises :class:`PinError`.
    """
    kwargs: Dict[str, Any] = dict(
        cells=None if cells is None else _triple("cells", cells),
        directions=directions,
        pins_per_entry=pins_per_entry,
        target_error=target_error,
        step=step,
        seed=seed,
        crop=crop,
        center_pins=center_pins,
        majorant=_triple("majorant", majorant),
        embed_density=None if embed_density is None else _triple("embed_density", embed_density),
        embed_control=embed_control,
        density_scale=density_scale,
        threads=threads,
        max_memory=max_memory,
        spacing=_floats3("spacing", spacing),
        origin=_floats3("origin", origin),
        # Passed for every input: the options that do not apply to it are refused there.
        grid=grid,
        levelset_to_fog=levelset_to_fog,
        dims=None if dims is None else _triple("dims", dims),
        voxel_type=voxel_type,
        endian=endian,
        clamp_negative=clamp_negative,
        nan_as_zero=nan_as_zero,
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

    a = np.asarray(array_or_path)
    if a.ndim != 3:
        raise ValueError(f"the volume array must be 3-D, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"the volume array must hold floats, got dtype {a.dtype}")
    # [x, y, z] indexing with x fastest in memory: the layout of the baker's dense grid.
    data = np.ascontiguousarray(a.astype(np.float32, copy=False).transpose(2, 1, 0))
    return json.loads(_native.bake("<array>", out, data=data, **kwargs))


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


class PinGrid:
    """An open pin grid. ``PinGrid(path)`` memory-maps the file (O(1), no copy);
    :meth:`from_bytes` copies a file's bytes. Safe to query from many threads at once.

    Only regular files are opened (a FIFO or a device raises :class:`PinError` at once, it
    is never waited on). A mapped file must not be truncated or rewritten in place while it
    is open: touching a vanished page raises SIGBUS, which kills the interpreter. Replace pin
    files atomically (write a new file, then rename it over the old one, as ``pinbake`` and
    :func:`bake` do): the mapping keeps the old file alive. Where that cannot be ruled out,
    use ``PinGrid.from_bytes(open(path, "rb").read())``."""

    __slots__ = ("_g",)

    def __init__(self, path: Union[str, "os.PathLike[str]"]) -> None:
        self._g = _native.PinGrid(os.fspath(path))

    @classmethod
    def from_bytes(cls, data: bytes) -> "PinGrid":
        g = cls.__new__(cls)
        g._g = _native.PinGrid.from_bytes(data)
        return g

    @property
    def info(self) -> Dict[str, Any]:
        """The grid description: dims, directions, pins, boxes, placement, bake settings."""
        return json.loads(self._g.info_json())

    def verify(self) -> None:
        """Checks every checksum and value (linear in the file size); raises PinError."""
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
        return self._g.sample_distance(
            o, d, t, seed, first_index, spatial_jitter, directional_jitter,
            chain_stride, lookup_point, start_inside, nearest_line,
        )
