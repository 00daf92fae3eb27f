"""socdiff.metrics on arrays equals what socdiff.evaluate (the engine's report) says of the same
forecast, and the metrics' known values."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

import socdiff
from socdiff import metrics
from conftest import run_cli


def test_metrics_equal_the_report(cli: Path, mupots: Path, tiny_model: Path, tmp_path: Path) -> None:
    fc_dir = tmp_path / "fc"
    run_cli(cli, ["forecast", "--model", str(tiny_model), "--input", str(mupots), "--sequence", "TS16",
                  "--observe", "30", "--horizon", "90", "--samples", "3", "--steps", "4", "--seed", "2", "--out", str(fc_dir)])
    report = socdiff.evaluate(mupots, forecasts={"m": fc_dir}, observe=30, metrics="mpjpe,ndms,apd,ade,fde")
    (method,) = report["methods"]
    data = socdiff.load_dataset(mupots)
    scene = data.sequence("TS16")
    samples = np.stack([s.positions for s in socdiff.load_dataset(fc_dir).sequences if re.fullmatch(r".*_s\d\d", s.name)])
    future, truth = samples[:, 30:], scene.positions[30:120]

    for kind in ("global", "root", "root_aligned"):
        stats = metrics.mpjpe(future, truth, fps=scene.fps, kind=kind, skeleton=scene.skeleton)
        for at, row in zip(stats, method["mpjpe"]["horizons"]):
            assert at is not None
            assert at.mean == pytest.approx(row[kind]["mean"], rel=1e-12)
            assert at.best == pytest.approx(row[kind]["best"], rel=1e-12)
    curve = metrics.mpjpe_curve(future, truth)
    assert curve.shape == (3, 90)
    assert curve.mean(axis=0) == pytest.approx(method["mpjpe"]["global_per_frame"]["values"], rel=1e-12)

    stochastic = method["stochastic"]
    assert metrics.apd(future) == pytest.approx(stochastic["apd"], rel=1e-12)
    assert metrics.ade(future, truth) == pytest.approx(stochastic["ade"], rel=1e-12)
    assert metrics.fde(future, truth) == pytest.approx(stochastic["fde"], rel=1e-12)

    database = metrics.NdmsDatabase(data.split("test"))
    assert database.words == report["settings"]["ndms"]["database"]["words"]
    assert metrics.ndms(samples, database, 30) == pytest.approx(method["ndms"]["mean"], rel=1e-12)


def test_known_values() -> None:
    # One person, two joints, at rest; samples offset by known vectors.
    truth = np.zeros((4, 1, 2, 3), np.float32)
    samples = np.zeros((2, 4, 1, 2, 3), np.float32)
    samples[0, ..., 0] = 0.3  # 0.3 m off on every joint
    samples[1, ..., 1] = 0.4  # 0.4 m off
    (at,) = metrics.mpjpe(samples, truth, fps=2.0, horizons=[1.0])
    assert at == pytest.approx(metrics.SampleStats(0.35, 0.3))
    # ADE over the 6-vector of two joints: ‖(0.3, 0, 0, 0.3, 0, 0)‖ = 0.3·√2.
    assert metrics.ade(samples, truth) == pytest.approx(0.3 * np.sqrt(2))
    assert metrics.fde(samples, truth) == pytest.approx(0.3 * np.sqrt(2))
    # APD: the whole 24-vector differs by (0.3, −0.4) per joint and frame: 0.5·√8.
    assert metrics.apd(samples) == pytest.approx(0.5 * np.sqrt(8))
    assert metrics.mpjpe(samples, truth, fps=2.0, horizons=[3.0]) == [None]


def test_bad_metric_inputs() -> None:
    with pytest.raises(ValueError, match=r"forecasts: shape \[4, 1, 2, 3\]"):
        metrics.apd(np.zeros((4, 1, 2, 3)))
    with pytest.raises(ValueError, match="ground truth has shape"):
        metrics.ade(np.zeros((1, 4, 1, 2, 3)), np.zeros((5, 1, 2, 3)))
    with pytest.raises(ValueError, match="needs the `skeleton`"):
        metrics.mpjpe(np.zeros((1, 4, 1, 2, 3)), np.zeros((4, 1, 2, 3)), fps=30, kind="root")
    with pytest.raises(ValueError, match="`kind`"):
        metrics.mpjpe_curve(np.zeros((1, 4, 1, 2, 3)), np.zeros((4, 1, 2, 3)), kind="procrustes")


def without_timings(value: object) -> object:
    """A report part without what differs between two runs (seconds, dates, the command)."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if "seconds" not in k and k not in ("created_unix_s", "command")}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def test_evaluate_returns_the_cli_report(cli: Path, mupots: Path, tiny_model: Path, tmp_path: Path) -> None:
    fc_dir = tmp_path / "fc"
    run_cli(cli, ["forecast", "--model", str(tiny_model), "--input", str(mupots), "--sequence", "TS17",
                  "--observe", "30", "--horizon", "60", "--samples", "2", "--steps", "3", "--out", str(fc_dir)])
    run_cli(cli, ["eval", "--reference", str(mupots), "--forecasts", f"m={fc_dir}", "--baselines", "zero-velocity,constant-velocity",
                  "--observe", "30", "--horizon", "60", "--metrics", "mpjpe,ndms,stochastic,plausibility", "--out", str(tmp_path / "cli")])
    ours = socdiff.evaluate(mupots, forecasts={"m": fc_dir}, baselines=["zero-velocity", "constant-velocity"], observe=30, horizon=60,
                            metrics="mpjpe,ndms,stochastic,plausibility", out=tmp_path / "py")
    theirs = json.loads((tmp_path / "cli" / "report.json").read_text())
    assert [m["label"] for m in ours["methods"]] == ["m", "zero-velocity", "constant-velocity"]
    for key in ("methods", "settings", "reference", "metrics"):
        assert without_timings(ours[key]) == without_timings(theirs[key]), key
    # With `out`, the same files as the CLI's.
    assert sorted(p.name for p in (tmp_path / "py").iterdir()) == sorted(p.name for p in (tmp_path / "cli").iterdir())
