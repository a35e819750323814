"""Type stubs of the `penumbra` extension module (src/python/module.cpp; docs/python.md)."""

import os
from typing import Any, Dict, List, Optional, Tuple, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

METHODS: Tuple[str, ...]
"""Estimator names: 'aci', 'aci-pixel' (render only), 'reference', 'mc-adaptive',
'mc-solid-angle', 'mc-ratio'."""

ACI_MODES: Tuple[str, ...]
"""ACI variants: 'tangent' (default), 'arcs', 'paper'."""

SETTING_RANGES: Dict[str, Tuple[int, int]]
"""Inclusive ranges of the integer settings (the CLI's and batch manifests')."""

_PathLike = Union[str, "os.PathLike[str]"]
_ArrayLike = npt.ArrayLike

class InputError(ValueError):
    """Bad input. str(e) is the CLI's error line without 'penumbra: error: '."""

    file: str
    """The input file ('' when none)."""
    where: str
    """JSON pointer, setting name or array index ('' when none)."""
    message: str
    """What is wrong."""

class _CameraDict(TypedDict):
    eye: Tuple[float, float, float]
    look_at: Tuple[float, float, float]
    up: Tuple[float, float, float]
    fov_deg: float
    width: int
    height: int

class Scene:
    """A scene: camera, lights, obstacles (level sets built when loaded) and receivers."""

    @staticmethod
    def load(path: _PathLike) -> "Scene":
        """Loads a scene file (JSON, docs/scene-format.md)."""
    @staticmethod
    def from_dict(
        d: Dict[str, Any], file: str = "<dict>", base_dir: Optional[_PathLike] = None
    ) -> "Scene":
        """A scene from the JSON model as a dict; `file` names it in messages."""
    @property
    def file(self) -> str: ...
    @property
    def lights(self) -> List[str]: ...
    @property
    def obstacles(self) -> List[str]: ...
    @property
    def camera(self) -> Optional[_CameraDict]: ...
    @property
    def build(self) -> Dict[str, Any]: ...
    def probe(
        self,
        points: _ArrayLike,
        normals: _ArrayLike,
        light: Optional[str] = None,
        method: str = "aci",
        *,
        aci_grid: Optional[int] = None,
        aci_steps: Optional[int] = None,
        aci_mode: Optional[str] = None,
        samples: Optional[int] = None,
        mc_threshold: Optional[float] = None,
        mc_max_depth: Optional[int] = None,
        mc_initial_depth: Optional[int] = None,
        seed: Optional[int] = None,
        threads: Optional[int] = None,
    ) -> Dict[str, Any]:
        """Form factor, gradient, shadow rays (and error bound) at each point.

        light: a light's name, None for the only light, or 'all' for the sum over every
        light (then 'per_light': (N, lights) float64, each light's form factor).

        Returns {'form_factor': (N,) float64, 'gradient': (N, 3) float64,
        'shadow_rays': (N,) int64, 'error_bound': (N,) float64 (aci, tangent mode only),
        'per_light': (N, lights) float64 (light='all' only), 'threads': int}.
        """
    def render(
        self,
        width: Optional[int] = None,
        height: Optional[int] = None,
        method: str = "aci",
        *,
        aci_grid: Optional[int] = None,
        aci_steps: Optional[int] = None,
        aci_mode: Optional[str] = None,
        aci_fixed_steps: Optional[bool] = None,
        aci_no_row_pairs: Optional[bool] = None,
        max_span: Optional[int] = None,
        samples: Optional[int] = None,
        mc_threshold: Optional[float] = None,
        mc_max_depth: Optional[int] = None,
        mc_initial_depth: Optional[int] = None,
        seed: Optional[int] = None,
        threads: Optional[int] = None,
        volume_cache: Optional[int] = None,
        volume_samples: Optional[int] = None,
        hide_volumes: Optional[bool] = None,
    ) -> Tuple[npt.NDArray[np.float32], Dict[str, Any]]:
        """The camera view as a float32 (H, W, 3) array ((H, W, 4) with alpha when the camera
        sees volumes) and the render statistics."""

def compare(
    a: Union[_ArrayLike, _PathLike],
    b: Union[_ArrayLike, _PathLike],
    mask: Union[_ArrayLike, _PathLike, None] = None,
) -> Dict[str, Any]:
    """Differences in 8-bit units: {width, height, channels, units, all, masked?}."""

def read_image(path: _PathLike) -> npt.NDArray[np.float32]:
    """An image file as float32 (H, W, C), or (H, W) for one channel."""

def write_image(path: _PathLike, image: _ArrayLike) -> None:
    """Writes .exr (linear float) or .png (sRGB 8-bit), atomically."""
