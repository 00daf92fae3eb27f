"""What calling through Python adds to a forecast: a 3-person minute (1,800 frames after 30
observed), K = 8, DDIM 50, with the bundled model — Python's wall clock against the engine's own
time for the same call, and against `socdiff forecast` of the same scene in the same run.

    python python/bench/forecast_overhead.py [--repeats 3] [--cli target/release/socdiff]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import socdiff

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cli", type=Path, default=REPO / "target" / "release" / "socdiff")
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "mupots3d")
    parser.add_argument("--sequence", default="TS16")
    args = parser.parse_args()
    model_path = REPO / "models" / "groups-mrt15" / "model.safetensors"
    model = socdiff.Model.load(model_path)
    scene = socdiff.load_dataset(args.data).sequence(args.sequence)
    request = {"observe": 30, "horizon": 1800, "samples": 8, "seed": 1, "steps": 50}
    py_wall: list[float] = []
    py_engine: list[float] = []
    cli_engine: list[float] = []
    cli_wall: list[float] = []
    for r in range(args.repeats):
        start = time.perf_counter()
        fc = model.forecast(scene.positions, skeleton=scene.skeleton, observe=30, horizon=1800, samples=8, seed=1, steps=50)
        py_wall.append(time.perf_counter() - start)
        py_engine.append(fc.provenance["timings"]["total_seconds"])
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "fc"
            cmd = [str(args.cli), "forecast", "--model", str(model_path), "--input", str(args.data), "--sequence", args.sequence,
                   "--joint-map", "auto", "--past-end", "--out", str(out)] + [f"--{k}={v}" for k, v in request.items()]
            start = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            cli_wall.append(time.perf_counter() - start)
            cli_engine.append(json.loads((out / "dataset.json").read_text())["forecast"]["timings"]["total_seconds"])
        print(f"repeat {r + 1}: python {py_wall[-1]:.3f} s (engine {py_engine[-1]:.3f} s)  cli forecast {cli_engine[-1]:.3f} s (process {cli_wall[-1]:.3f} s)")
    med = statistics.median
    print(f"{scene.num_persons} persons, 30 + 1800 frames, K = 8, DDIM 50, median of {args.repeats}:")
    print(f"  socdiff.Model.forecast, Python wall clock   {med(py_wall):8.3f} s")
    print(f"  the engine's time inside that call          {med(py_engine):8.3f} s  (Python adds {100 * (med(py_wall) / med(py_engine) - 1):+.2f} %)")
    print(f"  socdiff forecast, the engine's time         {med(cli_engine):8.3f} s  (Python against it: {100 * (med(py_wall) / med(cli_engine) - 1):+.2f} %)")
    print(f"  socdiff forecast, whole process             {med(cli_wall):8.3f} s  (loading, mapping, writing included)")


if __name__ == "__main__":
    main()
