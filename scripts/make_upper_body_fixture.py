#!/usr/bin/env python3
"""Writes cli/tests/fixtures/upper_body2: a small generated dataset that is not MuPoTS-shaped.

Two seated people face each other and gesture; 8 upper-body joints (no hips, no feet), y up,
metres, 30 fps, and `"hip_joints": null` in dataset.json, so the body frame must be inferred
from the shoulders. Generated from formulas (no recording); plain Python, no numpy.
Usage: python3 scripts/make_upper_body_fixture.py [OUT_DIR]
"""
import json, math, os, struct, sys

JOINTS = ["head", "neck", "left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist"]
BONES = [["neck", "head"], ["neck", "left_shoulder"], ["left_shoulder", "left_elbow"], ["left_elbow", "left_wrist"],
         ["neck", "right_shoulder"], ["right_shoulder", "right_elbow"], ["right_elbow", "right_wrist"]]


def write_npy(path, shape, values):
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (%s), }" % "".join(f"{d}, " for d in shape)
    header += " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode("latin1"))
        f.write(struct.pack(f"<{len(values)}f", *values))


def person_pose(t, p, seed):
    """Joint positions (y up) of person p at time t (seconds)."""
    side = 1.0 if p == 0 else -1.0                      # person 0 at x = -0.8 facing +x
    w = [0.7 + 0.13 * seed + 0.21 * p, 1.1 + 0.17 * seed - 0.1 * p, 0.35 + 0.05 * seed]
    yaw = 0.25 * math.sin(w[2] * t + seed + p)          # turning towards / away from the other
    fx, fz = side * math.cos(yaw), math.sin(yaw)        # forward in the ground plane (x, z)
    rx, rz = -fz, fx                                    # right = forward × up (right-handed, y up)
    base_x = -0.8 * side + 0.04 * math.sin(0.5 * t + p)
    sway = 0.05 * math.sin(w[0] * 0.5 * t + p)
    neck = (base_x + sway * fx, 1.15 + 0.01 * math.sin(2 * t + p), sway * fz)
    head = (neck[0] + 0.06 * fx * math.cos(w[1] * t), neck[1] + 0.2, neck[2] + 0.06 * fz)
    joints = {"neck": neck, "head": head}
    for name, s in (("left", -1.0), ("right", 1.0)):
        sh = (neck[0] + s * 0.19 * rx, neck[1] - 0.04, neck[2] + s * 0.19 * rz)
        lift = 0.6 + 0.5 * math.sin(w[0] * t + (0.0 if s < 0 else 1.7) + seed)
        bend = 0.9 + 0.6 * math.sin(w[1] * t + 0.5 * s + p)
        # Upper arm from hanging down towards forward by `lift`; forearm bent further by `bend`.
        el = (sh[0] + 0.28 * math.sin(lift) * fx, sh[1] - 0.28 * math.cos(lift), sh[2] + 0.28 * math.sin(lift) * fz)
        a = lift + bend
        wr = (el[0] + 0.25 * math.sin(a) * fx, el[1] - 0.25 * math.cos(a), el[2] + 0.25 * math.sin(a) * fz)
        joints[f"{name}_shoulder"], joints[f"{name}_elbow"], joints[f"{name}_wrist"] = sh, el, wr
    return [c for j in JOINTS for c in joints[j]]


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "cli", "tests", "fixtures", "upper_body2")
    seqs = [("talk1", "train", 360, 1), ("talk2", "train", 360, 2), ("talk3", "test", 240, 3)]
    entries = []
    for name, split, frames, seed in seqs:
        os.makedirs(os.path.join(out, split), exist_ok=True)
        values = []
        for f in range(frames):
            for p in range(2):
                values += person_pose(f / 30.0, p, seed)
        write_npy(os.path.join(out, split, f"{name}.npy"), (frames, 2, len(JOINTS), 3), values)
        entries.append({"name": name, "split": split, "file": f"{split}/{name}.npy", "frames": frames, "persons": 2})
    meta = {"name": "upper_body2", "fps": 30, "units": "metres", "up_axis": "y", "joints": JOINTS, "bones": BONES,
            "hip_joints": None, "sequences": entries,
            "description": "generated fixture: two seated people, upper body only (scripts/make_upper_body_fixture.py)"}
    with open(os.path.join(out, "dataset.json"), "w") as f:
        json.dump(meta, f, indent=1)


if __name__ == "__main__":
    main()
