"""Bad input raises one Python exception whose message names the problem; nothing crashes the
interpreter."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Type

import numpy as np
import pytest

import socdiff
from conftest import BUNDLED_MODEL


@pytest.fixture(scope="module")
def model() -> socdiff.Model:
    return socdiff.Model.load(BUNDLED_MODEL)


def scene(frames: int = 40, persons: int = 2, joints: int = 15) -> np.ndarray:
    rng = np.random.default_rng(1)
    base = socdiff.Skeleton.named("mrt15")
    assert base.num_joints == 15
    return (rng.normal(size=(frames, persons, joints, 3)) * 0.1 + [0.0, 0.0, 1.0]).astype(np.float32)


@pytest.mark.parametrize(
    "positions, message",
    [
        (np.zeros((40, 2, 15)), r"positions: shape \[40, 2, 15\], expected \[frames, persons, joints, 3\]"),
        (np.zeros((40, 2, 15, 2)), r"expected \[frames, persons, joints, 3\]"),
        (np.array(["a", "b"]), "cannot be read as float32"),
        (np.zeros((40, 2, 17, 3), np.float32), r"expected \[frames, persons, 15, 3\] for skeleton mrt15"),
        (np.zeros((40, 0, 15, 3), np.float32), "empty"),
    ],
)
def test_bad_arrays(model: socdiff.Model, positions: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        model.forecast(positions, observe=10, horizon=10)


def test_non_finite_positions_name_the_entry(model: socdiff.Model) -> None:
    x = scene()
    x[7, 1, 3, 2] = np.nan
    with pytest.raises(ValueError, match=r"non-finite position at frame 7, person 1, joint 3 \(left_ankle\)"):
        model.forecast(x, observe=10, horizon=10)
    x[7, 1, 3, 2] = 1e9
    with pytest.raises(ValueError, match="beyond"):
        model.forecast(x, observe=10, horizon=10)


def test_float64_and_lists_are_accepted(model: socdiff.Model) -> None:
    x = scene()
    a = model.forecast(x.astype(np.float64), observe=10, horizon=5, steps=2).samples
    b = model.forecast(x.tolist(), observe=10, horizon=5, steps=2).samples
    assert np.array_equal(a, b) and a.dtype == np.float32


@pytest.mark.parametrize(
    "options, error, message",
    [
        ({"observe": 0}, ValueError, "observe"),
        ({"observe": 41}, ValueError, "observe"),
        ({"horizon": 10**9}, ValueError, "frames"),
        ({"samples": 0}, ValueError, "sample"),
        ({"samples": 10**8}, ValueError, "samples"),
        ({"steps": 0}, ValueError, "`steps` must be at least 1"),
        ({"eta": float("nan")}, ValueError, "`eta`"),
        ({"sampler": "euler"}, ValueError, "`sampler` \"euler\": expected one of ddim, ddpm"),
        ({"fps": 0.0}, ValueError, "fps"),
        ({"observe": -1}, OverflowError, "negative"),
        ({"skeleton": "mupots18"}, ValueError, "unknown skeleton \"mupots18\""),
    ],
)
def test_bad_options(model: socdiff.Model, options: Dict[str, Any], error: Type[Exception], message: str) -> None:
    kwargs = {"observe": 10, "horizon": 10, "steps": 2, **options}
    with pytest.raises(error, match=message):
        model.forecast(scene(), **kwargs)


def test_joint_maps_need_the_names(model: socdiff.Model) -> None:
    with pytest.raises(ValueError, match=r"joint map custom → mrt15: no joint of custom is near target joint \"pelvis\""):
        model.forecast(scene(joints=3), joints=["a", "b", "c"], observe=10, horizon=10)
    # Named joints in another order map onto the model's.
    names = model.skeleton.joints[::-1]
    x = scene()
    reordered = x[:, :, ::-1]
    a = model.forecast(x, observe=10, horizon=5, steps=2).samples
    b = model.forecast(reordered, joints=names, observe=10, horizon=5, steps=2).samples
    assert np.array_equal(a, b)


def test_missing_and_malformed_models(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        socdiff.Model.load(tmp_path / "none")
    bad = tmp_path / "model.safetensors"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{}")
    with pytest.raises(ValueError, match="model.safetensors"):
        socdiff.Model.load(bad)
    with pytest.raises(ValueError, match="`weights`"):
        socdiff.Model.load(BUNDLED_MODEL, weights="best")


def test_complete_names_a_bad_spec(model: socdiff.Model) -> None:
    with pytest.raises(ValueError, match="missing"):
        model.complete(scene(), "elbows")
    with pytest.raises(ValueError, match="nose"):
        model.complete(scene(), "joints=nose")


def test_evaluate_errors(mupots: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown option `horizon_s`"):
        socdiff.evaluate(mupots, baselines="all", horizon_s=3)
    with pytest.raises(ValueError, match="nothing to evaluate"):
        socdiff.evaluate(mupots)
    with pytest.raises(ValueError, match="baseline"):
        socdiff.evaluate(mupots, baselines="random-walk")
