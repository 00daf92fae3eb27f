"""Forecasts from Python against the CLI's, bit for bit, and what sampling keeps fixed."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np
import pytest

import socdiff
from conftest import BUNDLED_MODEL, run_cli


def cli_samples(fc_dir: Path) -> np.ndarray:
    """The samples of a CLI forecast directory, stacked [K, frames, persons, joints, 3]."""
    ds = socdiff.load_dataset(fc_dir)
    samples = [s.positions for s in ds.sequences if re.fullmatch(r".*_s\d\d", s.name)]
    assert samples, [s.name for s in ds.sequences]
    return np.stack(samples)


def test_forecast_equals_the_cli_bit_for_bit(cli: Path, mupots: Path, tiny_model: Path, tmp_path: Path) -> None:
    out = tmp_path / "fc"
    run_cli(cli, ["forecast", "--model", str(tiny_model), "--input", str(mupots), "--sequence", "TS16",
                  "--observe", "30", "--horizon", "60", "--samples", "3", "--seed", "5", "--steps", "10", "--out", str(out)])
    scene = socdiff.load_dataset(mupots).sequence("TS16")
    model = socdiff.Model.load(tiny_model)
    fc = model.forecast(scene.positions, observe=30, horizon=60, samples=3, seed=5, steps=10)
    assert fc.samples.dtype == np.float32
    assert fc.samples.shape == (3, 90, scene.num_persons, 17, 3)
    expected = cli_samples(out)
    assert np.array_equal(fc.samples, expected)
    assert fc.provenance["seed"] == 5 and fc.provenance["steps"] == 10 and fc.provenance["samples"] == 3
    # The observed frames are the input's.
    assert np.array_equal(fc.samples[:, :30], np.broadcast_to(scene.positions[:30], (3, 30, scene.num_persons, 17, 3)))


def test_bundled_model_maps_another_skeleton_and_frame_rate(cli: Path, mupots: Path, tmp_path: Path) -> None:
    # MuPoTS-17 onto the bundled model's 15 joints, by name, as `--joint-map auto` does.
    out = tmp_path / "fc"
    run_cli(cli, ["forecast", "--model", str(BUNDLED_MODEL), "--input", str(mupots), "--sequence", "TS18", "--joint-map", "auto",
                  "--observe", "30", "--horizon", "30", "--samples", "2", "--seed", "2", "--steps", "5", "--out", str(out)])
    scene = socdiff.load_dataset(mupots).sequence("TS18")
    model = socdiff.Model.load(BUNDLED_MODEL)
    assert model.skeleton.name == "mrt15" and model.fps == 30.0
    fc = model.forecast(scene.positions, skeleton=scene.skeleton, observe=30, horizon=30, samples=2, seed=2, steps=5)
    assert fc.samples.shape == (2, 60, scene.num_persons, 15, 3)
    assert np.array_equal(fc.samples, cli_samples(out))


def test_samples_depend_on_the_seed_not_on_how_many_are_drawn(tiny_model: Path, mupots: Path) -> None:
    scene = socdiff.load_dataset(mupots).sequence("TS17")
    model = socdiff.Model.load(tiny_model)
    two = model.forecast(scene.positions, observe=20, horizon=20, samples=2, seed=3, steps=4).samples
    three = model.forecast(scene.positions, observe=20, horizon=20, samples=3, seed=3, steps=4).samples
    other = model.forecast(scene.positions, observe=20, horizon=20, samples=2, seed=4, steps=4).samples
    assert np.array_equal(two, three[:2])
    assert not np.array_equal(two[:, 20:], other[:, 20:])


def test_complete_keeps_the_known_frames(tiny_model: Path, mupots: Path) -> None:
    scene = socdiff.load_dataset(mupots).sequence("TS17")
    model = socdiff.Model.load(tiny_model)
    part = scene.positions[:60]
    fc = model.complete(part, "frames=20..40", samples=2, seed=1, steps=4)
    assert fc.samples.shape == (2, 60, scene.num_persons, 17, 3)
    for k in range(2):
        assert np.array_equal(fc.samples[k, :20], part[:20])
        assert np.array_equal(fc.samples[k, 40:], part[40:])
        assert not np.array_equal(fc.samples[k, 20:40], part[20:40])


def test_generate_from_a_layout(tiny_model: Path, mupots: Path) -> None:
    scene = socdiff.load_dataset(mupots).sequence("TS17")
    model = socdiff.Model.load(tiny_model)
    fc = model.generate(50, layout=scene.positions[:1], samples=2, seed=1, steps=4)
    assert fc.samples.shape == (2, 50, scene.num_persons, 17, 3)
    assert np.isfinite(fc.samples).all()
    assert fc.provenance["task"]["kind"] == "generate"


def test_sampling_releases_the_gil(tiny_model: Path, mupots: Path) -> None:
    scene = socdiff.load_dataset(mupots).sequence("TS16")
    model = socdiff.Model.load(tiny_model)
    ticks = 0
    done = threading.Event()

    def count() -> None:
        nonlocal ticks
        while not done.is_set():
            ticks += 1

    counter = threading.Thread(target=count)
    counter.start()
    try:
        before = ticks
        model.forecast(scene.positions, observe=30, horizon=300, samples=8, steps=20)
        during = ticks - before
    finally:
        done.set()
        counter.join()
    # Python code ran beside the engine: the counter advanced while the forecast computed.
    assert during > 1000


def test_a_stream_forecasts_each_frame_as_the_cli_forecasts_its_window(tiny_model: Path, mupots: Path) -> None:
    scene = socdiff.load_dataset(mupots).sequence("TS16")
    model = socdiff.Model.load(tiny_model)
    stream = model.stream(scene.num_persons, observe=8, horizon=6, samples=2, seed=3, steps=2)
    got = []
    for f in range(10):
        fc = stream.push(f / 30.0, scene.positions[f])
        got.append(fc)
        if f < 7:
            assert fc is None and stream.frames_needed == 7 - f
    assert got[7] is not None and got[9] is not None
    assert got[7].samples.shape == (2, 14, scene.num_persons, 17, 3)
    # The forecast at the 8th frame is that of the window, with the seed of the 8th frame.
    direct = model.forecast(scene.positions[:8], observe=8, horizon=6, samples=2, seed=3 + 8, steps=2)
    assert np.array_equal(got[7].samples, direct.samples)
    assert np.array_equal(got[9].samples[:, :8], np.broadcast_to(scene.positions[2:10], (2, 8, scene.num_persons, 17, 3)))
    with pytest.raises(ValueError, match=r"expected \[persons, joints, 3\]"):
        stream.push(10 / 30.0, scene.positions[10:12])
    bad = scene.positions[10].copy()
    bad[0, 3, 1] = np.nan
    with pytest.raises(ValueError, match="person 0, joint 3"):
        stream.push(10 / 30.0, bad)
    with pytest.raises(ValueError, match="less than half a frame"):
        stream.push(9 / 30.0, scene.positions[10])
    assert stream.push(10 / 30.0, scene.positions[10]) is not None


def test_a_distilled_student_samples_with_its_own_steps(cli: Path, mupots: Path, tiny_model: Path, tmp_path: Path) -> None:
    student = tmp_path / "student"
    run_cli(cli, ["distill", "--teacher", str(tiny_model), "--data", str(mupots), "--out", str(student),
                  "--steps", "2", "--teacher-steps", "3", "--round-steps", "2"])
    scene = socdiff.load_dataset(mupots).sequence("TS16")
    fc = socdiff.Model.load(student).forecast(scene.positions, observe=30, horizon=30, samples=2, seed=1)
    assert fc.provenance["steps"] == 2
    out = tmp_path / "fc"
    run_cli(cli, ["forecast", "--model", str(student), "--input", str(mupots), "--sequence", "TS16",
                  "--observe", "30", "--horizon", "30", "--samples", "2", "--seed", "1", "--out", str(out)])
    assert np.array_equal(fc.samples, cli_samples(out))
    # A model that was not distilled: 50 steps unless told.
    teacher = socdiff.Model.load(tiny_model).forecast(scene.positions, observe=30, horizon=10, samples=1)
    assert teacher.provenance["steps"] == 50
