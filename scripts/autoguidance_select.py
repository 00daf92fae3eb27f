#!/usr/bin/env python3
"""Issue 17: the table of scripts/autoguidance_probe.sh for one model, and the autoguidance
setting it selects. The choice is made on the train split only: the highest NDMS against the
train split's words among guided settings whose motion-kind JS distance to the train split is
no worse than the unguided model's (guidance may not buy NDMS by collapsing onto locomotion,
which NDMS rewards most). The test split's row of that setting is the reported result.
Usage: scripts/autoguidance_select.py OUT_DIR MODEL_NAME"""
import json
import sys

out, name = sys.argv[1], sys.argv[2]


def rows(split):
    report = json.load(open(f"{out}/eval-{name}-{split}/report.json"))
    return {m["label"]: m for m in report["methods"]}


train, test = rows("train"), rows("test")


def speed(m):
    v = m["speed"]["per_frame"]["values"]
    return sum(v) / len(v)


cols = "setting | NDMS train | kinds JS train | NDMS test ↑ | speed m/s | bone mm ↓ | jerk m/s³ | precision ↑ | recall ↑ | kinds JS test ↓ | % run | % wave"
print("| " + cols + " |")
print("|" + "---|" * len(cols.split("|")))
for label, m in test.items():
    t, k = train[label], m["kinds"]
    share = {lab: 100 * w / max(1, sum(k["windows"])) for lab, w in zip(k["labels"], k["windows"])}
    print(
        f"| {label} | {t['ndms']['mean']:.3f} | {t['kinds']['js']:.3f} | {m['ndms']['mean']:.3f} | {speed(m):.2f} | "
        f"{m['plausibility']['bone_length_mm']:.1f} | {m['plausibility']['jerk_m_s3']:.0f} | {m['coverage']['precision']:.3f} | "
        f"{m['coverage']['recall']:.3f} | {k['js']:.3f} | {share['run']:.0f} | {share['wave']:.0f} |"
    )
limit = train[name]["kinds"]["js"]
allowed = [lab for lab in train if lab.startswith(name + "-w") and train[lab]["kinds"]["js"] <= limit]
if not allowed:
    print(f"no guided setting keeps the kinds JS at or below the unguided {limit:.3f}")
    sys.exit(0)
best = max(allowed, key=lambda lab: train[lab]["ndms"]["mean"])
print(f"chosen on the train split: {best} (train NDMS {train[best]['ndms']['mean']:.3f}, kinds JS {train[best]['kinds']['js']:.3f} ≤ {limit:.3f}); "
      f"test NDMS {test[best]['ndms']['mean']:.3f}")
