#!/usr/bin/env python3
"""Issue 17: how many training windows each bandai2 motion gives (train split, windows of
WINDOW frames every STRIDE frames, as `socdiff train --window --stride` cuts them), and how many
takes have at least one window. Standard library only.
Usage: python3 scripts/window_shares.py [DATA_DIR] [WINDOW] [STRIDE]   (defaults ../shared/data/bandai2 96 5)"""
import collections, json, sys

data = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/bandai2"
window = int(sys.argv[2]) if len(sys.argv) > 2 else 96
stride = int(sys.argv[3]) if len(sys.argv) > 3 else 5
takes, windows = collections.Counter(), collections.Counter()
for s in json.load(open(f"{data}/dataset.json"))["sequences"]:
    if s["split"] == "train" and s["frames"] >= window:
        takes[s["motion"]] += 1
        windows[s["motion"]] += (s["frames"] - window) // stride + 1
total = sum(windows.values())
for m in sorted(windows):
    print(f"{m:22s} {takes[m]:4d} takes {windows[m]:6d} windows {100 * windows[m] / total:5.1f} %")
