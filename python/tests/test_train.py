"""Training from Python against the CLI's run of the same configuration, progress events, and
Ctrl-C leaving a checkpoint that resumes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Dict, List

import pytest

import socdiff
from conftest import TINY, run_cli


def log_losses(run: Path) -> List[float]:
    lines = (run / "train_log.jsonl").read_text().splitlines()
    return [json.loads(line)["loss"] for line in lines if "loss" in json.loads(line)]


def test_train_equals_the_cli_run_of_the_same_config(cli: Path, mupots: Path, tiny_model: Path, tmp_path: Path) -> None:
    events: List[Dict[str, Any]] = []
    summary = socdiff.train(mupots, tmp_path / "py", steps=6, hidden=16, batch=4, save_every=3, val_every=0, seed=7, progress=events.append)
    assert TINY == ["--steps", "6", "--hidden", "16", "--batch", "4", "--save-every", "3", "--val-every", "0", "--seed", "7"]
    cli_losses = log_losses(tiny_model)
    assert len(cli_losses) == 6
    assert log_losses(tmp_path / "py") == cli_losses
    assert summary["losses"] == pytest.approx(cli_losses, rel=0, abs=0)
    assert (summary["first_step"], summary["last_step"], summary["stopped"]) == (0, 6, False)
    assert summary["config"]["model"]["hidden"] == 16 and summary["config"]["preset"] == "recommended"
    assert [e["step"] for e in events if e["kind"] == "step"] == [1, 2, 3, 4, 5, 6]
    assert [e["step"] for e in events if e["kind"] == "saved"] == [3, 6]
    assert events[0]["kind"] == "started" and events[0]["total_steps"] == 6
    # The two runs' weights are the same too: their forecasts are.
    scene = socdiff.load_dataset(mupots).sequence("TS16")
    a = socdiff.Model.load(tiny_model).forecast(scene.positions, samples=1, steps=3, horizon=10).samples
    b = socdiff.Model.load(tmp_path / "py").forecast(scene.positions, samples=1, steps=3, horizon=10).samples
    assert (a == b).all()


def test_unknown_or_bad_options_name_the_keyword(mupots: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown option `hiden`.*hidden"):
        socdiff.train(mupots, tmp_path / "a", steps=2, hiden=16)
    with pytest.raises(ValueError, match="`batch`"):
        socdiff.train(mupots, tmp_path / "b", steps=2, batch="many")
    with pytest.raises(ValueError, match="preset"):
        socdiff.train(mupots, tmp_path / "c", steps=2, preset="fast")
    with pytest.raises(FileNotFoundError, match="nowhere"):
        socdiff.train(tmp_path / "nowhere", tmp_path / "d", steps=2)
    assert not (tmp_path / "a").exists() and not (tmp_path / "d").exists()


def test_an_exception_in_the_progress_callback_stops_with_a_checkpoint(mupots: Path, tmp_path: Path) -> None:
    def stop_at_4(event: Dict[str, Any]) -> None:
        if event["kind"] == "step" and event["step"] == 4:
            raise RuntimeError("enough")

    with pytest.raises(RuntimeError, match="enough"):
        socdiff.train(mupots, tmp_path / "run", steps=50, hidden=16, batch=4, save_every=100, val_every=0, progress=stop_at_4)
    resumed = socdiff.train(mupots, tmp_path / "run", resume=True, steps=6)
    assert (resumed["first_step"], resumed["last_step"]) == (4, 6)


CHILD = """
import sys, socdiff
from pathlib import Path
marker = Path(sys.argv[3])
def progress(event):
    if event["kind"] == "step" and event["step"] == 5:
        marker.write_text("5")
try:
    socdiff.train(sys.argv[1], sys.argv[2], steps=1_000_000, hidden=16, batch=4, save_every=100_000, val_every=0, progress=progress)
except KeyboardInterrupt:
    print("KeyboardInterrupt raised")
    raise
"""


def test_ctrl_c_leaves_a_checkpoint_that_resumes(mupots: Path, tmp_path: Path) -> None:
    run, marker = tmp_path / "run", tmp_path / "marker"
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(mupots), str(run), str(marker)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert child.poll() is None, child.communicate()
        assert time.monotonic() < deadline, "training never reached step 5"
        time.sleep(0.02)
    child.send_signal(signal.SIGINT)
    stdout, stderr = child.communicate(timeout=120)
    assert child.returncode != 0
    assert "KeyboardInterrupt raised" in stdout and "KeyboardInterrupt" in stderr
    meta = json.loads((run / "checkpoint.json").read_text())
    stopped_at = meta["step"]
    assert stopped_at >= 5
    resumed = socdiff.train(mupots, run, resume=True, steps=stopped_at + 2)
    assert (resumed["first_step"], resumed["last_step"], resumed["stopped"]) == (stopped_at, stopped_at + 2, False)
