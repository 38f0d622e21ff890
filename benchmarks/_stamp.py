"""Provenance stamp for benchmark outputs: date, library version, CPU, threads, torch."""

from __future__ import annotations

import datetime as _dt
import platform

import torch

import tdfields


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def stamp(device: str = "cpu") -> dict:
    info = {
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "tdfields_version": tdfields.__version__,
        "torch_version": torch.__version__,
        "python": platform.python_version(),
        "cpu": cpu_name(),
        "torch_threads": torch.get_num_threads(),
        "device": device,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name()
    return info


def stamp_line(info: dict) -> str:
    dev = info.get("gpu", info["device"])
    return (f"Measured {info['date']} with tdfields {info['tdfields_version']}, torch {info['torch_version']}, "
            f"on {info['cpu']} ({info['torch_threads']} threads), device {dev}.")


def write_timings(out, times: dict, label: str, **fields) -> dict:
    """Print the median of each list of seconds in ``times`` (``{setting: [s, ...]}``, one line each, prefixed by
    ``label``) and write them, every value, the stamp, the command line and ``fields`` to the JSON file ``out``."""
    import json
    import statistics
    import sys
    from pathlib import Path

    medians = {k: statistics.median(v) for k, v in times.items()}
    for k, v in medians.items():
        print(f"{label}{k}: {1e3 * v:.1f} ms (median of {len(times[k])})")
    result = {"stamp": stamp(), "command": " ".join(sys.argv), **fields, "seconds": times, "median_s": medians}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(result, indent=1))
    return result
