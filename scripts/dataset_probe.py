#!/usr/bin/env python3
"""Diagnostics on a dataset directory (dataset.json + float .npy files [frames, persons, joints, 3]),
used by scripts/ndms_diagnostics.sh to ask what NDMS responds to:

    dataset_probe.py smooth SRC DST SIGMA    copy SRC to DST with every joint coordinate smoothed
                                             over time (Gaussian, SIGMA frames, renormalised at the
                                             ends): is frame-to-frame jitter what NDMS penalises?
    dataset_probe.py split-speed SRC THR     DST = SRC-fast and SRC-slow: the sequences whose mean
                                             root (joint 0) ground speed is above / at most THR m/s

Pure Python (no numpy) so that it runs wherever the binary does.
"""
import array
import ast
import json
import math
import os
import shutil
import struct
import sys


def load(path):
    """(header bytes, shape, flat values) of a version-1 .npy file of little-endian floats."""
    raw = open(path, "rb").read()
    if raw[:6] != b"\x93NUMPY" or raw[6] != 1:
        sys.exit(f"error: {path}: not a version-1 .npy file")
    header_len = struct.unpack("<H", raw[8:10])[0]
    header = ast.literal_eval(raw[10:10 + header_len].decode())
    if header["descr"] not in ("<f4", "<f8") or header["fortran_order"]:
        sys.exit(f"error: {path}: expected little-endian float32/64 in C order, got {header}")
    values = array.array("f" if header["descr"] == "<f4" else "d")
    values.frombytes(raw[10 + header_len:])
    return raw[:10 + header_len], header["shape"], values


def smooth(src, dst, sigma):
    if os.path.exists(dst):
        sys.exit(f"error: {dst} exists")
    shutil.copytree(src, dst)
    radius = int(3 * sigma) + 1
    kernel = [math.exp(-0.5 * (k / sigma) ** 2) for k in range(-radius, radius + 1)]
    meta = json.load(open(os.path.join(dst, "dataset.json")))
    for seq in meta["sequences"]:
        path = os.path.join(dst, seq["file"])
        head, shape, a = load(path)
        frames = shape[0]
        per_frame = len(a) // frames
        out = array.array(a.typecode, a)
        for t in range(frames):
            taps = [(t + k - radius, w) for k, w in enumerate(kernel) if 0 <= t + k - radius < frames]
            total = sum(w for _, w in taps)
            for i in range(per_frame):
                out[t * per_frame + i] = sum(w * a[tt * per_frame + i] for tt, w in taps) / total
        os.chmod(path, 0o644)
        open(path, "wb").write(head + out.tobytes())
    print(f"{len(meta['sequences'])} sequences smoothed (sigma {sigma} frames) -> {dst}")


def split_speed(src, threshold):
    meta = json.load(open(os.path.join(src, "dataset.json")))
    groups = {"fast": [], "slow": []}
    speeds = []
    for seq in meta["sequences"]:
        _, shape, a = load(os.path.join(src, seq["file"]))
        frames, per_frame = shape[0], len(a) // shape[0]
        if frames < 2:
            continue
        # joint 0 of person 0; z is up in every dataset socdiff writes
        step = sum(math.hypot(a[(t + 1) * per_frame] - a[t * per_frame], a[(t + 1) * per_frame + 1] - a[t * per_frame + 1])
                   for t in range(frames - 1))
        speed = step / (frames - 1) * meta["fps"]
        speeds.append(speed)
        groups["fast" if speed > threshold else "slow"].append(seq)
    for name, seqs in groups.items():
        dst = src.rstrip("/") + "-" + name
        if os.path.exists(dst):
            sys.exit(f"error: {dst} exists")
        for seq in seqs:
            os.makedirs(os.path.dirname(os.path.join(dst, seq["file"])), exist_ok=True)
            shutil.copyfile(os.path.join(src, seq["file"]), os.path.join(dst, seq["file"]))
        json.dump(dict(meta, sequences=seqs), open(os.path.join(dst, "dataset.json"), "w"), indent=1)
        mean = sum(s for s in speeds if (s > threshold) == (name == "fast")) / max(1, len(seqs))
        print(f"{name}: {len(seqs)} sequences, mean root speed {mean:.2f} m/s -> {dst}")


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "smooth":
        smooth(sys.argv[2], sys.argv[3], float(sys.argv[4]))
    elif len(sys.argv) == 4 and sys.argv[1] == "split-speed":
        split_speed(sys.argv[2], float(sys.argv[3]))
    else:
        sys.exit(__doc__)
