"""Type stubs of the extension module ``tissue._tissue`` (re-exported by
``tissue``); the docstrings of the module itself are the reference."""

from collections.abc import Callable, Sequence
from os import PathLike
from typing import Any, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str

class TissueError(Exception):
    """Bad input (a mesh, a file, a parameter) or a failed computation."""

ArrayLike = npt.ArrayLike
Path = Union[str, PathLike[str]]
Mesh = tuple[ArrayLike, ArrayLike]
"""``(vertices, triangles)``: ``(v, 3)`` coordinates and ``(m, 3)`` indices."""
Progress = Callable[[dict[str, Any]], None]

def sample(
    surface: Union[Path, Mesh],
    particles: int,
    seed: int = 0,
    backend: str = "auto",
    progress: Optional[Progress] = None,
) -> Model: ...
def load_model(path: Path) -> Model: ...
def phantom_breast() -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]: ...
def phantom_breast_sagged() -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]: ...
def save_motion(matrix: ArrayLike, path: Path, space: str = "lps") -> None: ...
def load_cloud(path: Path, space: str = "lps") -> npt.NDArray[np.float64]: ...
def rigid_fit(
    points: ArrayLike, surface: Union[Path, Mesh, Any], reach: Optional[float] = None
) -> dict[str, Any]: ...
def fiducial_fit(observed: ArrayLike, model: ArrayLike) -> dict[str, Any]: ...

class Model:
    def __len__(self) -> int: ...
    @property
    def positions(self) -> npt.NDArray[np.float64]: ...
    @property
    def radii(self) -> npt.NDArray[np.float64]: ...
    @property
    def on_surface(self) -> npt.NDArray[np.bool_]: ...
    @property
    def surface(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]: ...
    @property
    def connections(self) -> npt.NDArray[np.int64]: ...
    @property
    def report(self) -> Optional[dict[str, Any]]: ...
    def save(self, path: Path) -> None: ...
    def deformer(
        self,
        backend: str = "auto",
        force: str = "elastic",
        poisson: Optional[float] = None,
        max_iterations: Optional[int] = None,
        progress: Optional[Progress] = None,
        observed: Optional[ArrayLike] = None,
    ) -> Deformer: ...
    def deformer_in_posture(
        self,
        deformed: Union[Path, Mesh, ArrayLike],
        gravity_rest: Sequence[float],
        gravity_deformed: Sequence[float],
        density: float = 1000.0,
        stiffness_kpa: Optional[float] = None,
        held: Optional[ArrayLike] = None,
        unit: str = "mm",
        backend: str = "auto",
        poisson: Optional[float] = None,
        max_iterations: Optional[int] = None,
        progress: Optional[Progress] = None,
        fit_particles: Optional[int] = 4000,
        scan: bool = False,
        noise: Optional[float] = None,
    ) -> Deformer: ...

class Deformer:
    @property
    def posture(self) -> Optional[dict[str, Any]]: ...
    @property
    def backend(self) -> str: ...
    @property
    def positions(self) -> npt.NDArray[np.float64]: ...
    def solve(
        self,
        surface: Union[Path, Mesh, ArrayLike],
        progress: Optional[Progress] = None,
    ) -> dict[str, Any]: ...
    def carry(self, points: ArrayLike) -> npt.NDArray[np.float64]: ...
    def uncertainty(
        self,
        points: Optional[ArrayLike] = None,
        samples: int = 16,
        surface_noise: float = 0.5,
        surface_correlation: float = 10.0,
        poisson_range: tuple[float, float] = (0.45, 0.495),
        load_spread: float = 0.14,
        gravity_spread: float = 3.0,
        posture_spread: float = 1.0,
        seed: int = ...,
    ) -> dict[str, Any]: ...
    def carry_rigid(
        self, vertices: ArrayLike
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    def save_particles(self, path: Path, space: str = "lps") -> None: ...
    def save_displacement_field(
        self, path: Path, spacing: Optional[float] = None, space: str = "lps"
    ) -> None: ...
    def carry_file(
        self, points: Path, output: Path, space: str = "lps"
    ) -> npt.NDArray[np.float64]: ...
    def match_observation(
        self,
        surface: Optional[Any] = None,
        cloud: Optional[Any] = None,
        noise: Optional[float] = None,
        from_last: bool = False,
        surface_smoothing: Optional[float] = None,
        predict: bool = True,
    ) -> dict[str, Any]: ...
    def reset(self) -> None: ...
