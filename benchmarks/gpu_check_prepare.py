"""Pack what the GPU check needs into two git-ignored folders of the repository, for the device tool's ``carry``.

* ``.gpu_data/tum_fr1_rpy``: the first ``--frames`` associated frames of the shared TUM excerpt (the whole excerpt
  with the repository would pass the 64 MiB a device call may carry), with its index files cut to them;
* ``.whl/``: wheels of the pure-Python packages ``import slam`` needs that the GPU image lacks (trimesh), for
  Python 3.12.

Then, on the device: ``bash benchmarks/gpu_check.sh --data .gpu_data/tum_fr1_rpy --out $OUT`` with
``carry: [".gpu_data", ".whl"]``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cut_excerpt(src: Path, dst: Path, frames: int) -> int:
    pairs = [ln for ln in (src / "associations.txt").read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    keep = pairs[:frames]
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    for ln in keep:
        _, rgb, _, depth = ln.split()
        shutil.copy(src / rgb, dst / rgb)
        shutil.copy(src / depth, dst / depth)
    (dst / "associations.txt").write_text("\n".join(keep) + "\n")
    names = {ln.split()[1] for ln in keep} | {ln.split()[3] for ln in keep}
    for index in ("rgb.txt", "depth.txt"):
        lines = (src / index).read_text().splitlines()
        (dst / index).write_text("\n".join(ln for ln in lines if ln.startswith("#") or ln.split()[-1] in names) + "\n")
    shutil.copy(src / "groundtruth.txt", dst / "groundtruth.txt")
    return sum(p.stat().st_size for p in dst.rglob("*") if p.is_file())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default=str(ROOT.parent / "shared" / "data" / "tum_fr1_rpy"))
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--no-wheels", action="store_true")
    args = ap.parse_args(argv)
    exclude = ROOT / ".git" / "info" / "exclude"
    text = exclude.read_text() if exclude.exists() else ""
    for pattern in ("/.gpu_data/", "/.whl/"):
        if pattern not in text:
            text += f"\n{pattern}"
    exclude.write_text(text.strip() + "\n")
    size = cut_excerpt(Path(args.src), ROOT / ".gpu_data" / "tum_fr1_rpy", args.frames)
    print(f".gpu_data/tum_fr1_rpy: {args.frames} frames, {size / 2**20:.1f} MiB")
    if not args.no_wheels:
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                        "--python-version", "3.12", "--implementation", "cp", "-d", str(ROOT / ".whl"),
                        "trimesh>=4.0"], check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
