#!/usr/bin/env python3
"""Copies an evenly spaced subset of a dataset directory's sequences (dataset.json + .npy files),
e.g. to fit bandai2's train split under the device machine's 64 MiB transfer limit:

    python3 scripts/subset_dataset.py ../shared/data/bandai2 .scale/bandai2 --split train \
        --min-frames 96 --max-mb 40

Keeps the sequences of --split with at least --min-frames frames, then every k-th of them (in
dataset order, smallest k ≥ 1) so that their .npy files total at most --max-mb MB; --motions
keeps only sequences with those motion labels (bandai2). The copy is
for the run only: the licences of the data forbid committing it.
"""
import argparse
import json
import os
import shutil
import sys


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--split", default="train")
    ap.add_argument("--min-frames", type=int, default=0)
    ap.add_argument("--max-mb", type=float, default=40.0)
    ap.add_argument("--motions", default="", help="comma-separated motion labels to keep (all if empty)")
    a = ap.parse_args()
    motions = set(filter(None, a.motions.split(",")))
    meta = json.load(open(os.path.join(a.src, "dataset.json")))
    seqs = [s for s in meta["sequences"] if s["split"] == a.split and s["frames"] >= a.min_frames
            and (not motions or s.get("motion") in motions)]
    if not seqs:
        sys.exit(f"error: {a.src}: no {a.split} sequence with at least {a.min_frames} frames"
                 + (f" and motion in {sorted(motions)}" if motions else ""))
    size = lambda s: os.path.getsize(os.path.join(a.src, s["file"])) + (
        os.path.getsize(os.path.join(a.src, s["valid_file"])) if s.get("valid_file") else 0)
    k = 1
    while sum(size(s) for s in seqs[::k]) > a.max_mb * 1e6:
        k += 1
    keep = seqs[::k]
    if os.path.exists(a.dst) and os.listdir(a.dst):
        sys.exit(f"error: {a.dst} exists and is not empty")
    for s in keep:
        for key in ("file", "valid_file"):
            if s.get(key):
                os.makedirs(os.path.dirname(os.path.join(a.dst, s[key])), exist_ok=True)
                shutil.copyfile(os.path.join(a.src, s[key]), os.path.join(a.dst, s[key]))
    meta["sequences"] = keep
    meta["subset_note"] = (f"every {k}th {a.split} sequence with >= {a.min_frames} frames of {a.src}"
                           + (f", motions {sorted(motions)}" if motions else ""))
    json.dump(meta, open(os.path.join(a.dst, "dataset.json"), "w"), indent=1)
    frames = sum(s["frames"] for s in keep)
    print(f"{len(keep)} of {len(seqs)} sequences (every {k}th), {frames} frames, "
          f"{sum(size(s) for s in keep) / 1e6:.1f} MB -> {a.dst}")


if __name__ == "__main__":
    main()
