"""Turn a pytest-benchmark JSON of test_field_speed.py into the docs table (medians and ratios); docs/results.md is then rewritten by ``python benchmarks/results_page.py``.

    python benchmarks/field_speed_table.py benchmarks/results/field_speed.json --threads 1
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# (label, numerator case, denominator case); cases are "<config>:<backend>" as in test_field_speed.py
RATIOS = [
    ("CP geometry / ESLAM grid_sample tri-plane (target <= 0.25)", "geometry/lrslam-cp:fused",
     "geometry/eslam-grid_sample:torch"),
    ("CP geometry / tdfields tri-plane, both fused", "geometry/lrslam-cp:fused", "geometry/eslam-triplane:fused"),
    ("Six-axis appearance / ESLAM grid_sample tri-plane (target <= 0.5)", "appearance/lrslam-six_axis:fused",
     "appearance/eslam-grid_sample:torch"),
    ("Six-axis appearance / tdfields tri-plane, both fused", "appearance/lrslam-six_axis:fused",
     "appearance/eslam-triplane:fused"),
    ("Six-axis fused / Six-axis reference", "appearance/lrslam-six_axis:fused", "appearance/lrslam-six_axis:reference"),
    ("CP fused / CP reference", "geometry/lrslam-cp:fused", "geometry/lrslam-cp:reference"),
    # on a GPU (present only when the run had one)
    ("CUDA: CP Triton / ESLAM grid_sample tri-plane", "geometry/lrslam-cp:cuda-triton",
     "geometry/eslam-grid_sample:cuda-torch"),
    ("CUDA: Six-axis Triton / ESLAM grid_sample tri-plane", "appearance/lrslam-six_axis:cuda-triton",
     "appearance/eslam-grid_sample:cuda-torch"),
    ("CUDA: Six-axis Triton / Six-axis reference", "appearance/lrslam-six_axis:cuda-triton",
     "appearance/lrslam-six_axis:cuda-reference"),
]


def medians(data: dict) -> dict:
    med = {}
    for b in data["benchmarks"]:
        test, case = b["name"].split("[", 1)
        med[(test, case.rstrip("]"))] = b["stats"]["median"]
    return med


def table(data: dict, version: str) -> str:
    med = medians(data)
    info = data.get("machine_info", {})
    cpu = info.get("cpu", {}).get("brand_raw", "unknown CPU")
    threads = data.get("threads", "?")
    gpu = any(case.split(":")[1].startswith("cuda") for _, case in med)
    lines = [f"Measured {data.get('datetime', '?')[:16]} UTC on {cpu}, {threads} thread(s), device cpu"
             f"{' and ' + data['gpu'] if gpu and data.get('gpu') else (' and cuda' if gpu else '')}, "
             f"tdfields {version}; medians of pytest-benchmark rounds, 40k uniformly random points in the room0 box.",
             "", "| field | backend | forward ms | forward+backward ms |", "|---|---|---|---|"]
    cases = sorted({case for _, case in med})
    for case in cases:
        name, backend = case.split(":")
        f, fb = med.get(("test_forward", case)), med.get(("test_forward_backward", case))
        lines.append(f"| {name} | {backend} | {'-' if f is None else f'{1e3 * f:.1f}'} | "
                     f"{'-' if fb is None else f'{1e3 * fb:.1f}'} |")
    lines += ["", "| ratio | forward | forward+backward |", "|---|---|---|"]
    for label, a, b in RATIOS:
        if label.startswith("CUDA") and not gpu:
            continue
        cells = []
        for test in ("test_forward", "test_forward_backward"):
            x, y = med.get((test, a)), med.get((test, b))
            cells.append("-" if x is None or y is None else f"{x / y:.2f}")
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("json", type=Path, help="output of pytest --benchmark-json")
    p.add_argument("--threads", default="?", help="thread count the run used (for the stamp)")
    p.add_argument("--gpu", default="", help="GPU name for the stamp when the run had CUDA cases")
    args = p.parse_args(argv)
    if not args.json.is_file():
        print(f"field_speed_table: error: no such file: {args.json}", file=sys.stderr)
        return 2
    data = json.loads(args.json.read_text())
    data.setdefault("threads", args.threads)
    data.setdefault("gpu", args.gpu)
    sys.path.insert(0, str(ROOT))
    import tdfields

    text = table(data, tdfields.__version__)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
