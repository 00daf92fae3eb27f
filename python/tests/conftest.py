"""Shared fixtures: the repository, the real data in ../shared/data, the CLI binary, and a
tiny model trained by the CLI once per session."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import List

import pytest

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"
BUNDLED_MODEL = REPO / "models" / "groups-mrt15" / "model.safetensors"


def data_dir(name: str) -> Path:
    """A dataset of ../shared/data: skipped when absent, failed when SOCDIFF_REQUIRE_DATA=1 (CI)."""
    path = DATA / name
    if not path.exists():
        message = f"{path} is missing"
        if os.environ.get("SOCDIFF_REQUIRE_DATA") == "1":
            pytest.fail(message)
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def mupots() -> Path:
    return data_dir("mupots3d")


@pytest.fixture(scope="session")
def cli() -> Path:
    """The `socdiff` binary: $SOCDIFF_BIN, or target/release/socdiff (built when missing)."""
    given = os.environ.get("SOCDIFF_BIN")
    if given:
        return Path(given)
    binary = REPO / "target" / "release" / "socdiff"
    if not binary.exists():
        subprocess.run(["cargo", "build", "--release", "-p", "socdiff-cli"], cwd=REPO, check=True)
    return binary


def run_cli(cli: Path, args: List[str]) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([str(cli), *args], capture_output=True, text=True)
    assert result.returncode == 0, f"socdiff {' '.join(args)}: {result.stderr}"
    return result


# A tiny training run: hidden 16, batch 4, six steps of the recommended recipe on MuPoTS.
TINY = ["--steps", "6", "--hidden", "16", "--batch", "4", "--save-every", "3", "--val-every", "0", "--seed", "7"]


@pytest.fixture(scope="session")
def tiny_model(cli: Path, mupots: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tiny") / "run"
    run_cli(cli, ["train", "--data", str(mupots), "--out", str(out), *TINY])
    return out
