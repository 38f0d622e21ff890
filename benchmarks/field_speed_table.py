"""Turn a pytest-benchmark JSON of test_field_speed.py into the docs table (medians and LRSLAM/ESLAM ratios).

    python benchmarks/field_speed_table.py benchmarks/results/field_speed.json --docs
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAIRS = {"geometry": ("geometry/lrslam-cp", "geometry/eslam-triplane"),
         "appearance": ("appearance/lrslam-six_axis", "appearance/eslam-triplane"),
         "appearance, factor path": ("appearance/lrslam-six_axis-factors", "appearance/eslam-triplane")}


def table(data: dict) -> str:
    med = {}
    for b in data["benchmarks"]:
        test, name = b["name"].split("[", 1)
        med[(test, name.rstrip("]"))] = b["stats"]["median"]
    info = data.get("machine_info", {})
    cpu = info.get("cpu", {}).get("brand_raw", "unknown CPU")
    lines = [f"Measured {data.get('datetime', '?')[:16]} UTC on {cpu}, {info.get('cpu', {}).get('count', '?')} cores, "
             f"torch threads as default, device cpu, tdfields {data.get('version', '')}".rstrip(", ") + ".", "",
             "| quantity | pass | LRSLAM (median ms) | ESLAM tri-plane (median ms) | ratio LRSLAM / ESLAM |",
             "|---|---|---|---|---|"]
    for quantity, (ours, theirs) in PAIRS.items():
        for test, label in (("test_forward", "forward"), ("test_forward_backward", "forward+backward")):
            a, b = med.get((test, ours)), med.get((test, theirs))
            if a is None or b is None:
                continue
            lines.append(f"| {quantity} ({ours.split('-', 1)[1]} vs tri-plane) | {label} | {a * 1e3:.1f} | "
                         f"{b * 1e3:.1f} | {a / b:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("json", type=Path, help="output of pytest --benchmark-json")
    p.add_argument("--docs", action="store_true", help="write the table into docs/benchmarks.md")
    args = p.parse_args(argv)
    if not args.json.is_file():
        print(f"field_speed_table: error: no such file: {args.json}", file=sys.stderr)
        return 2
    data = json.loads(args.json.read_text())
    sys.path.insert(0, str(ROOT))
    import tdfields

    data["version"] = tdfields.__version__
    text = table(data)
    print(text)
    if args.docs:
        doc = ROOT / "docs" / "benchmarks.md"
        body = doc.read_text()
        start, end = "<!-- field-speed:start -->", "<!-- field-speed:end -->"
        doc.write_text(body[: body.index(start) + len(start)] + "\n" + text + "\n" + body[body.index(end):])
    return 0


if __name__ == "__main__":
    sys.exit(main())
