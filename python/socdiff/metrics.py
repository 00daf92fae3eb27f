"""The metrics ``socdiff eval`` reports, on numpy arrays (metres).

Forecasts are ``[K, frames, persons, joints, 3]``, the ground truth ``[frames, persons, joints,
3]`` over the same frames; for pose errors frame 0 is the first forecast frame (pass
``samples[:, observe:]`` and ``truth[observe:]``), so a horizon of h seconds is frame
``round(h * fps) - 1``. Best of K takes whole samples: all persons come from one sample.
"""

from __future__ import annotations

from typing import Any, List, NamedTuple, Optional, Protocol, Sequence, Tuple

import numpy as np
import numpy.typing as npt

from . import _native

__all__ = ["NdmsDatabase", "SampleStats", "ade", "apd", "fde", "mpjpe", "mpjpe_curve", "ndms"]


class _HasHips(Protocol):
    @property
    def left(self) -> int: ...

    @property
    def right(self) -> int: ...


class SampleStats(NamedTuple):
    """An error over K samples: their mean, and the best (smallest) of them."""

    mean: float
    best: float


_KINDS = ("global", "root", "root_aligned")


def _f32(a: npt.ArrayLike, what: str) -> npt.NDArray[np.float32]:
    try:
        return np.ascontiguousarray(a, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: cannot be read as float32 numbers ({e})") from None


def _hips(kind: str, skeleton: Optional[_HasHips]) -> Tuple[int, int]:
    if kind not in _KINDS:
        raise ValueError(f"`kind` {kind!r}: expected one of {', '.join(_KINDS)}")
    if skeleton is None:
        if kind != "global":
            raise ValueError(f"`kind` {kind!r} needs the `skeleton` (its left and right hips)")
        return (0, 0)
    return (skeleton.left, skeleton.right)


def mpjpe_curve(forecasts: npt.ArrayLike, truth: npt.ArrayLike, *, kind: str = "global", skeleton: Optional[_HasHips] = None) -> npt.NDArray[np.float64]:
    """Per-sample, per-frame error ``[K, frames]``: ``global`` (MPJPE: mean joint distance),
    ``root`` (the hip midpoint) or ``root_aligned`` (joints relative to each pose's hip
    midpoint; these two need ``skeleton``)."""
    left, right = _hips(kind, skeleton)
    curve: npt.NDArray[np.float64] = _native.pose_error_curve(_f32(forecasts, "forecasts"), _f32(truth, "truth"), left, right, kind)
    return curve


def mpjpe(
    forecasts: npt.ArrayLike,
    truth: npt.ArrayLike,
    *,
    fps: float,
    horizons: Sequence[float] = (1.0, 2.0, 3.0),
    kind: str = "global",
    skeleton: Optional[_HasHips] = None,
) -> List[Optional[SampleStats]]:
    """Mean and best of K error at each horizon in seconds (None beyond the forecast), as
    ``socdiff eval``'s MPJPE table."""
    left, right = _hips(kind, skeleton)
    stats = _native.mpjpe_at_horizons(_f32(forecasts, "forecasts"), _f32(truth, "truth"), left, right, float(fps), [float(h) for h in horizons], kind)
    return [None if s is None else SampleStats(*s) for s in stats]


def ade(forecasts: npt.ArrayLike, truth: npt.ArrayLike) -> float:
    """Average displacement error of the best sample: ``min_k mean_{t,p} ‖X̂ − X‖`` over each
    person's pose vector."""
    return float(_native.ade(_f32(forecasts, "forecasts"), _f32(truth, "truth")))


def fde(forecasts: npt.ArrayLike, truth: npt.ArrayLike) -> float:
    """Final displacement error of the best sample (the last frame)."""
    return float(_native.fde(_f32(forecasts, "forecasts"), _f32(truth, "truth")))


def apd(forecasts: npt.ArrayLike) -> float:
    """Average pairwise distance between samples (diversity); 0 for one sample."""
    return float(_native.apd(_f32(forecasts, "forecasts")))


class _SceneLike(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def fps(self) -> float: ...

    @property
    def skeleton(self) -> Any: ...

    @property
    def positions(self) -> npt.NDArray[np.float32]: ...


class NdmsDatabase:
    """NDMS's reference: every motion word of a set of scenes (one skeleton and frame rate),
    indexed for exact nearest-neighbour search. ``socdiff eval`` builds it from the scored
    split; ``joints`` "default" (head, shoulders, elbows, wrists, knees, ankles), "all", or
    comma-separated names."""

    def __init__(self, scenes: Sequence[_SceneLike], joints: str = "default") -> None:
        items = [(s.name, float(s.fps), s.skeleton._native(), _f32(s.positions, f"scene {s.name!r}")) for s in scenes]
        self._native = _native.NdmsDatabase(items, joints)

    @property
    def words(self) -> int:
        return self._native.words

    def score(self, forecasts: npt.ArrayLike, first_forecast_frame: int) -> Tuple[float, npt.NDArray[np.float64]]:
        """NDMS of every sample and person of ``forecasts`` (whole canvases: the observed
        frames before ``first_forecast_frame`` are needed by the first words): the mean, and
        the per-word curve."""
        mean, curve = self._native.score(_f32(forecasts, "forecasts"), first_forecast_frame)
        return float(mean), curve


def ndms(forecasts: npt.ArrayLike, database: NdmsDatabase, first_forecast_frame: int) -> float:
    """Mean NDMS of ``forecasts`` against ``database`` (:meth:`NdmsDatabase.score`)."""
    return database.score(forecasts, first_forecast_frame)[0]
