"""Datasets round-trip between Python and dataset directories."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import socdiff


def assert_same(a: socdiff.Dataset, b: socdiff.Dataset) -> None:
    assert a.name == b.name and a.metadata == b.metadata
    assert [s.name for s in a.sequences] == [s.name for s in b.sequences]
    for x, y in zip(a.sequences, b.sequences):
        assert (x.split, x.fps, x.skeleton, x.persons, x.metadata) == (y.split, y.fps, y.skeleton, y.persons, y.metadata)
        assert x.positions.dtype == y.positions.dtype == np.float32
        assert np.array_equal(x.positions, y.positions)
        assert (x.valid is None) == (y.valid is None)
        if x.valid is not None and y.valid is not None:
            assert np.array_equal(x.valid, y.valid)
        assert x.signals.keys() == y.signals.keys()
        for k in x.signals:
            assert np.array_equal(x.signals[k], y.signals[k])


def test_mupots_round_trips(mupots: Path, tmp_path: Path) -> None:
    data = socdiff.load_dataset(mupots)
    assert len(data.sequences) == 20 and len(data.split("test")) == 5
    assert data.skeleton.joints == socdiff.Skeleton.named("mupots17").joints
    ts1 = data.sequence("TS1")
    assert ts1.positions.shape == (201, 2, 17, 3) and ts1.fps == 30.0 and ts1.split == "train"
    socdiff.save_dataset(tmp_path / "copy", data)
    assert_same(data, socdiff.load_dataset(tmp_path / "copy"))


def test_a_dataset_made_in_python_round_trips(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    skeleton = socdiff.Skeleton.named("mrt15")
    valid = np.ones((40, 2), bool)
    valid[5:9, 1] = False
    seq = socdiff.Sequence(
        name="walk",
        split="test",
        fps=25.0,
        skeleton=skeleton,
        positions=(rng.normal(size=(40, 2, 15, 3)) * 0.3 + [0, 0, 1]).astype(np.float32),
        valid=valid,
        signals={"speaking": (rng.random((40, 2)) > 0.5).astype(np.float32)},
        persons=[("a", "buyer"), ("b", None)],
        metadata={"source": "made in a test"},
    )
    data = socdiff.Dataset("made", [seq], {"licence": "CC0"})
    socdiff.save_dataset(tmp_path / "made", data)
    assert_same(data, socdiff.load_dataset(tmp_path / "made"))
    # The CLI reads it too.
    assert json.loads((tmp_path / "made" / "dataset.json").read_text())["sequences"][0]["name"] == "walk"


def test_save_refuses_bad_data_and_writes_nothing(tmp_path: Path) -> None:
    skeleton = socdiff.Skeleton.named("mrt15")
    bad = socdiff.Sequence("x", "train", 30.0, skeleton, np.zeros((10, 1, 14, 3), np.float32))
    with pytest.raises(ValueError, match="expected \\[frames, persons, 15, 3\\]"):
        socdiff.save_dataset(tmp_path / "out", socdiff.Dataset("d", [bad]))
    nan = socdiff.Sequence("x", "train", 30.0, skeleton, np.full((10, 1, 15, 3), np.nan, np.float32))
    with pytest.raises(ValueError, match="non-finite"):
        socdiff.save_dataset(tmp_path / "out", socdiff.Dataset("d", [nan]))
    wrong_split = socdiff.Sequence("x", "dev", 30.0, skeleton, np.zeros((10, 1, 15, 3), np.float32))
    with pytest.raises(ValueError, match="dev"):
        socdiff.save_dataset(tmp_path / "out", socdiff.Dataset("d", [wrong_split]))
    assert not (tmp_path / "out").exists()
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("mine")
    ok = socdiff.Sequence("x", "train", 30.0, skeleton, np.zeros((10, 1, 15, 3), np.float32))
    with pytest.raises((OSError, ValueError)):
        socdiff.save_dataset(tmp_path / "taken", socdiff.Dataset("d", [ok]))
    assert [p.name for p in (tmp_path / "taken").iterdir()] == ["keep.txt"]


def test_load_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing"):
        socdiff.load_dataset(tmp_path / "missing")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "dataset.json").write_text("{not json")
    with pytest.raises(ValueError, match="dataset.json"):
        socdiff.load_dataset(tmp_path / "broken")
