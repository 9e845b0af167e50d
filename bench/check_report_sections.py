#!/usr/bin/env python3
"""Checks that the performance report shows the time-to-accuracy and serving sections, and the
matcher `--matcher auto` runs on a real set, once its numbers hold them: adds a held-out curve, a
localization curve and a server's measurements to the first scale row of docs/performance.json,
the recorded matching cost to its first real set, regenerates the report from it and reads the
sections back.
Usage: check_report_sections.py HSCLOC_BENCH PERFORMANCE_JSON WORK_DIR"""
import json
import pathlib
import subprocess
import sys

bench, source, work = sys.argv[1], pathlib.Path(sys.argv[2]), pathlib.Path(sys.argv[3])
work.mkdir(parents=True, exist_ok=True)
results = json.loads(source.read_text())
# Only the first row keeps curves, so the picture holds exactly the two injected below.
for other in results["scale"][1:]:
    other.pop("held_out_curve", None)
    other.pop("localization_curve", None)
row = results["scale"][0]
row["held_out_curve"] = [
    {"iteration": 100, "seconds": 30.0, "point_accuracy": 0.62},
    {"iteration": 200, "seconds": 61.0, "point_accuracy": 0.93},
    {"iteration": 300, "seconds": 95.0, "point_accuracy": 0.91},
]
row["localization_curve"] = [
    {"iteration": 100, "seconds": 30.0, "day": 0.4, "night": 0.1},
    {"iteration": 300, "seconds": 95.0, "day": 0.96, "night": 0.78},
]
row.update({"serve_rss_mb": 235.0, "process_baseline_rss_mb": 167.0, "serve_load_s": 0.15})
results["real_sets"][0]["auto"] = {"matcher": "nn", "keypoints": 1000, "images": 10,
                                   "network_ms": 27.14, "nearest_neighbor_ms": 12.36,
                                   "cheaper": "nn"}
(work / "performance.json").write_text(json.dumps(results))
subprocess.run([bench, "--from-json", "--json", str(work / "performance.json"), "--report",
                str(work / "performance.md")], check=True, stderr=subprocess.DEVNULL)
report = (work / "performance.md").read_text()
preset = row["preset"]
expected = [
    "## Time to accuracy",
    f"| {preset} | 61 s (step 200) | 91.0 % at 95 s | 93.0 % at 61 s | 40 / 10 % at 30 s "
    "| 96 / 78 % at 95 s |",
    "## Serving a map",
    f"| {preset} | {row['build_map_peak_mb']:.0f} MB | 235 MB | 68 MB | 167 MB | 0.15 s |",
    "`--matcher auto` (the default) runs **nn** on this map: matching 1000 keypoints against 10 "
    "images took the network 27.1 ms and nearest neighbour 12.4 ms on one core when it was "
    "trained.",
]
errors = [f"missing: {line}" for line in expected if line not in report]
svg = work / "performance_training.svg"
if not svg.exists() or svg.read_text().count("<path") != 2:
    errors.append("performance_training.svg: expected a held-out and a localization curve")
if errors:
    print("\n".join(errors))
    sys.exit(1)
print("report: time-to-accuracy, serving and auto-matcher sections as measured")
