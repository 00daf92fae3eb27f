#!/usr/bin/env python3
"""Mean and spread over sample seeds of `socdiff eval --generated` rows.

Rows labelled NAME-sSEED (or NAME-seedSEED) in one or more report.json files are grouped by NAME;
each group prints its number of seeds, the mean and sample standard deviation of NDMS, and the
mean of speed, bone deviation, jerk, precision, recall, kinds JS and the shares of run and wave
windows where the report has them.
Usage: python3 scripts/seed_summary.py EVAL_DIR [EVAL_DIR ...]
"""
import json
import re
import statistics
import sys

FIELDS = [
    ("speed m/s", lambda m: m.get("speed", {}).get("forecast_mean")),
    ("bone mm", lambda m: m.get("plausibility", {}).get("bone_length_mm")),
    ("jerk m/s³", lambda m: m.get("plausibility", {}).get("jerk_m_s3")),
    ("precision", lambda m: m.get("coverage", {}).get("precision")),
    ("recall", lambda m: m.get("coverage", {}).get("recall")),
    ("kinds JS", lambda m: m.get("kinds", {}).get("js")),
    ("% run", lambda m: kind_share(m, "run")),
    ("% wave", lambda m: kind_share(m, "wave")),
]


def kind_share(m, kind):
    """Percent of the generated windows the kinds classifier labels `kind`."""
    k = m.get("kinds")
    if not k or kind not in k["labels"] or sum(k["windows"]) == 0:
        return None
    return 100.0 * k["windows"][k["labels"].index(kind)] / sum(k["windows"])


def main(dirs):
    groups = {}
    for d in dirs:
        for m in json.load(open(f"{d}/report.json"))["methods"]:
            hit = re.fullmatch(r"(.+?)-s(?:eed)?(\d+)", m["label"])
            if hit:
                groups.setdefault(hit.group(1), []).append(m)
    head = ["rows", "seeds", "NDMS mean", "NDMS sd"] + [f for f, _ in FIELDS]
    print(" | ".join(head))
    for name, rows in groups.items():
        ndms = [m["ndms"]["mean"] for m in rows]
        sd = statistics.stdev(ndms) if len(ndms) > 1 else float("nan")
        cells = [name, str(len(rows)), f"{statistics.mean(ndms):.3f}", f"{sd:.3f}"]
        for f, get in FIELDS:
            vals = [v for v in map(get, rows) if v is not None]
            digits = 1 if f.startswith("%") or "jerk" in f or "bone" in f else 3
            cells.append(f"{statistics.mean(vals):.{digits}f}" if len(vals) == len(rows) else "-")
        print(" | ".join(cells))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
