"""Type stubs of the native module (Rust, pyo3). Use the typed wrappers in ``socdiff``."""

from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np
import numpy.typing as npt

__version__: str

_Skeleton = Tuple[str, List[str], List[Tuple[int, int]], int, int]
_F32 = npt.NDArray[np.float32]
_F64 = npt.NDArray[np.float64]

class Model:
    @staticmethod
    def load(path: str, weights: str = ...) -> Model: ...
    @property
    def skeleton(self) -> _Skeleton: ...
    @property
    def fps(self) -> float: ...
    @property
    def step(self) -> int: ...
    @property
    def path(self) -> str: ...
    @property
    def config_json(self) -> str: ...
    def forecast(
        self,
        positions: _F32,
        skeleton: Optional[_Skeleton],
        fps: Optional[float],
        name: str,
        observe: int,
        horizon: int,
        samples: int,
        seed: int,
        sampler: str,
        steps: Optional[int],
        eta: float,
        conditioning: str,
        clean_known: str,
        joint_map: bool,
    ) -> Tuple[_F32, str]: ...
    def complete(
        self,
        positions: _F32,
        missing: str,
        skeleton: Optional[_Skeleton],
        fps: Optional[float],
        name: str,
        samples: int,
        seed: int,
        sampler: str,
        steps: Optional[int],
        eta: float,
        conditioning: str,
        clean_known: str,
        joint_map: bool,
    ) -> Tuple[_F32, str]: ...
    def stream(
        self, persons: int, observe: int, horizon: int, samples: int, seed: int, sampler: str, steps: Optional[int], eta: float
    ) -> Stream: ...
    def generate(
        self,
        frames: int,
        persons: int,
        layout: Optional[_F32],
        skeleton: Optional[_Skeleton],
        fps: Optional[float],
        samples: int,
        seed: int,
        sampler: str,
        steps: Optional[int],
        eta: float,
    ) -> Tuple[_F32, str]: ...

class Stream:
    def push(self, time: float, frame: _F32) -> Optional[Tuple[_F32, str]]: ...
    @property
    def frames_needed(self) -> int: ...

class NdmsDatabase:
    def __init__(self, scenes: List[Tuple[str, float, _Skeleton, _F32]], joints: str) -> None: ...
    @property
    def words(self) -> int: ...
    def score(self, forecasts: _F32, first_forecast_frame: int) -> Tuple[float, _F64]: ...

def start_workers() -> None: ...
def skeleton(name: str) -> _Skeleton: ...
def skeleton_names() -> List[str]: ...
def load_dataset(path: str) -> Dict[str, Any]: ...
def save_dataset(path: str, name: str, metadata: str, sequences: List[Dict[str, Any]]) -> None: ...
def train(
    data: List[str],
    out: str,
    preset: str,
    config: Optional[str],
    resume: bool,
    init: Optional[str],
    force: bool,
    overrides: List[str],
    device: str,
    progress: Optional[Callable[[Dict[str, Any]], None]],
) -> Dict[str, Any]: ...
def evaluate(args: List[str], write: bool) -> str: ...
def pose_error_curve(forecasts: _F32, truth: _F32, left: int, right: int, kind_name: str) -> _F64: ...
def mpjpe_at_horizons(
    forecasts: _F32, truth: _F32, left: int, right: int, fps: float, horizons: List[float], kind_name: str
) -> List[Optional[Tuple[float, float]]]: ...
def ade(forecasts: _F32, truth: _F32) -> float: ...
def fde(forecasts: _F32, truth: _F32) -> float: ...
def apd(forecasts: _F32) -> float: ...
