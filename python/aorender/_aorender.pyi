"""Type stubs of the native module `aorender._aorender` (re-exported by `aorender`)."""

import os
from typing import Any, Dict, Literal, Optional, Sequence, Tuple, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

Hemisphere = Literal["cosine", "uniform", "cosine-polar"]
SamplerName = Literal["sobol", "independent", "stratified", "grid"]
Values = Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]

class Camera(TypedDict, total=False):
    eye: Sequence[float]
    look_at: Sequence[float]
    up: Sequence[float]
    fov: float
    ortho_height: float

def ambient_occlusion(
    V: npt.ArrayLike,
    F: npt.ArrayLike,
    P: npt.ArrayLike,
    N: npt.ArrayLike,
    samples: int = 256,
    *,
    hemisphere: Hemisphere = "cosine",
    sampler: SamplerName = "independent",
    max_distance: Optional[float] = None,
    seed: int = 0,
    replicate: Optional[int] = None,
    sky: Union[None, str, Dict[str, Any]] = None,
    surface_tolerance: Optional[float] = None,
    device: str = "auto",
) -> Values:
    """AO of the mesh (V, F) at the points P about the normals N: (ao, std_error).

    AO = 1/π ∫ V(p, ω) cos θ dω over the hemisphere about n: 1 fully open, 0 closed.
    libigl's igl.embree.ambient_occlusion returns instead the fraction of uniformly
    drawn directions (not weighted by cos θ) that hit the mesh; 1 minus it is the
    unweighted uniform visibility, a different quantity (equal only where the point is
    fully open or fully closed).

    std_error is valid for "independent" samples; for "sobol" and "stratified" pass
    replicate=N (samples per independently randomised replicate, e.g. 16), else it is the
    spread of single samples, an overestimate.

    Each point is taken on the triangle it lies on within surface_tolerance (None: 2**-18
    of the largest coordinate of the point and the triangle), and its rays start off the
    triangle by its distance to it; points on no triangle are traced as given, and a
    UserWarning counts them.
    """

class Scene:
    """A scene prepared for AO queries, images and bakes; one BVH per device, kept."""

    @staticmethod
    def from_arrays(V: npt.ArrayLike, F: npt.ArrayLike, name: str = "arrays") -> "Scene":
        """One triangle mesh: V (n, 3) positions, F (m, 3) vertex indices."""
    @staticmethod
    def load(
        path: Union[str, "os.PathLike[str]"],
        *,
        allow_external_uris: bool = False,
        read_budget: Optional[int] = None,
    ) -> "Scene":
        """A scene file (.toml) or a mesh file (.obj, .ply, .gltf, .glb, optionally .gz),
        read within read_budget bytes (default: AORENDER_READ_BUDGET, else half of the
        available memory); glTF URIs outside the file's folder only when allowed."""
    @property
    def name(self) -> str: ...
    @property
    def triangles(self) -> int: ...
    @property
    def camera(self) -> Camera: ...
    def ambient_occlusion(
        self,
        P: npt.ArrayLike,
        N: npt.ArrayLike,
        samples: int = 256,
        *,
        hemisphere: Hemisphere = "cosine",
        sampler: SamplerName = "independent",
        max_distance: Optional[float] = None,
        seed: int = 0,
        replicate: Optional[int] = None,
        sky: Union[None, str, Dict[str, Any]] = None,
        surface_tolerance: Optional[float] = None,
        device: str = "auto",
    ) -> Values:
        """AO at the points P about the normals N: (ao, std_error), float64, k each."""
    def render(
        self,
        width: int,
        height: int,
        spp: int,
        *,
        camera: Optional[Camera] = None,
        hemisphere: Hemisphere = "cosine",
        sampler: SamplerName = "independent",
        seed: int = 0,
        max_distance: Optional[float] = None,
        replicate: Optional[int] = None,
        sky: Union[None, str, Dict[str, Any]] = None,
        background: float = 0.0,
        device: str = "auto",
    ) -> Tuple[npt.NDArray[np.float32], Dict[str, Any]]:
        """An AO image (height, width), row 0 at the top, and the render's figures."""
    def bake(
        self,
        samples: int = 256,
        *,
        at: Literal["vertices", "faces"] = "vertices",
        hemisphere: Hemisphere = "cosine",
        sampler: SamplerName = "independent",
        seed: int = 0,
        max_distance: Optional[float] = None,
        replicate: Optional[int] = None,
        sky: Union[None, str, Dict[str, Any]] = None,
        device: str = "auto",
        output: Union[None, str, "os.PathLike[str]"] = None,
        std_error: bool = False,
        colors: bool = False,
        overwrite: bool = False,
    ) -> Values:
        """AO at every vertex (or face) of the scene's meshes, in order: (ao, std_error)."""
