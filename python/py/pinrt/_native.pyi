# Typed stub of the compiled module (python/src/lib.rs). The public API is pinrt/__init__.py.
from os import PathLike
from typing import Any, Dict, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

class PinError(Exception): ...

RENDER_LOOKUP: Dict[str, Any]
THESIS_LOOKUP: Dict[str, Any]

class PinGrid:
    def __init__(self, path: Union[str, PathLike[str]]) -> None: ...
    @staticmethod
    def from_bytes(data: bytes) -> PinGrid: ...
    def verify(self) -> None: ...
    def info_json(self) -> str: ...
    def transmittance(
        self,
        origins: npt.NDArray[np.float32],
        directions: npt.NDArray[np.float32],
        t_max: npt.NDArray[np.float32],
        seed: int,
        first_index: int,
        spatial_jitter: float,
        directional_jitter: float,
        chain_stride: int,
        lookup_point: str,
        start_inside: bool,
        nearest_line: int = ...,
    ) -> npt.NDArray[np.float32]: ...
    def sample_distance(
        self,
        origins: npt.NDArray[np.float32],
        directions: npt.NDArray[np.float32],
        t_max: npt.NDArray[np.float32],
        seed: int,
        first_index: int,
        spatial_jitter: float,
        directional_jitter: float,
        chain_stride: int,
        lookup_point: str,
        start_inside: bool,
        nearest_line: int = ...,
    ) -> npt.NDArray[np.float32]: ...

def bake(
    input: str,
    output: Union[str, PathLike[str]],
    *,
    data: Optional[Union[npt.NDArray[np.float32], npt.NDArray[np.float64]]] = ...,
    spacing: Optional[Tuple[float, float, float]] = ...,
    origin: Optional[Tuple[float, float, float]] = ...,
    cells: Optional[Tuple[int, int, int]] = ...,
    directions: Optional[str] = ...,
    pins_per_entry: Optional[int] = ...,
    target_error: Optional[float] = ...,
    step: float = ...,
    seed: int = ...,
    crop: bool = ...,
    center_pins: bool = ...,
    majorant: Tuple[int, int, int] = ...,
    embed_density: Union[str, Tuple[int, int, int], None] = ...,
    embed_control: Union[int, bool, str, None] = ...,
    density_scale: float = ...,
    threads: Optional[int] = ...,
    max_memory: Optional[int] = ...,
    grid: Optional[str] = ...,
    levelset_to_fog: bool = ...,
    dims: Optional[Tuple[int, int, int]] = ...,
    voxel_type: Optional[str] = ...,
    endian: Optional[str] = ...,
    clamp_negative: bool = ...,
    nan_as_zero: bool = ...,
    vdb_worker: Optional[Union[str, PathLike[str]]] = ...,
    held_bytes: int = ...,
    backend: str = ...,
    max_bytes: Optional[int] = ...,
) -> str: ...
def check_array_memory(
    shape: Tuple[int, ...], held: int, max_memory: Optional[int] = ...
) -> None: ...
def vdb_worker(args: list[str]) -> int: ...
