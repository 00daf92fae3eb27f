"""README.md's Python example runs, and it and these tests pass `mypy --strict`."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from conftest import REPO, data_dir


def readme_example() -> str:
    text = (REPO / "README.md").read_text()
    section = text.split("## Python", 1)[1]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "README.md has no Python example under ## Python"
    return match.group(1)


def test_the_readme_example_runs(tmp_path: Path) -> None:
    data_dir("mupots3d")
    script = tmp_path / "readme_example.py"
    script.write_text(readme_example())
    result = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    shape, apd = result.stdout.splitlines()
    assert shape == "(8, 120, 3, 15, 3)"
    assert 0.0 < float(apd) < 100.0


def test_mypy_strict_passes_on_the_example_and_the_tests(tmp_path: Path) -> None:
    script = tmp_path / "readme_example.py"
    script.write_text(readme_example())
    tests = Path(__file__).resolve().parent
    result = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--no-incremental", str(script), str(tests)], cwd=tests, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
