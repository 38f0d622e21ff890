"""Packaging check: the wheel without extras is the field library alone, and it holds the whole source tree.

    python3 .ci/check_wheel.py [--keep DIR] [--fresh-kernel-cache]

1. builds the wheel (``pip wheel --no-deps .``, with build isolation, as a user's ``pip install .`` does);
2. checks that it holds every package under ``tdfields/`` and ``slam/`` (every folder with a ``.py`` file, so
   a new sub-package that forgot its ``__init__.py`` fails here) and every preset YAML under ``slam/configs``;
3. creates a fresh virtual environment (no system site packages), installs ``torch==2.13.0`` (the offline CPU
   build) and then the wheel without extras;
4. checks that none of the SLAM client's packages came along;
5. outside the checkout, imports tdfields and builds, queries and back-propagates through every kind
   (dense_grid, triplane, vector_matrix, cp, six_axis, multires, hybrid) on the fused CPU kernels, comparing
   values and gradients with the PyTorch reference path (kernels from the user's kernel cache, which holds
   compiled kernels by the hash of their generated source, so a hit is the same kernel; with
   ``--fresh-kernel-cache`` every kernel is generated and JIT-compiled anew, about a minute more);
6. checks that ``import slam`` raises the one-line MissingDependencyError and ``lrslam`` exits with 2 and one
   line, both naming the missing packages and ``pip install "tdfields[slam]"``.

Prints the time of each step; exits non-zero with a message on the first failure.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TORCH = "torch==2.13.0"  # the CPU build on this machine; a bare "torch" would pull a multi-GB CUDA build
SLAM_SIDE = ("trimesh", "scikit-image", "matplotlib", "embreex", "imageio", "scipy", "tqdm")

# runs inside the fresh environment, from a folder outside the checkout
PROBE = r'''
import json, sys
import torch
import tdfields
from tdfields import kernels

assert "site-packages" in tdfields.__file__, tdfields.__file__
box = [[-0.5, 0.7], [0.1, 1.0], [-0.3, 0.4]]
specs = {
    "dense_grid": {"kind": "dense_grid", "aabb": box, "grid_shape": [5, 4, 6], "channels": 4},
    "triplane": {"kind": "triplane", "aabb": box, "grid_shape": [5, 4, 6], "channels": 4},
    "vector_matrix": {"kind": "vector_matrix", "aabb": box, "grid_shape": [5, 4, 6], "channels": 4, "rank": 3},
    "cp": {"kind": "cp", "aabb": box, "grid_shape": [5, 4, 6], "channels": 4, "rank": 3},
    "six_axis": {"kind": "six_axis", "aabb": box, "grid_shape": [5, 4, 6], "channels": 4, "rank": 3},
    "multires": {"kind": "cp", "aabb": box, "cell_size": [0.3, 0.1], "channels": 4, "rank": 2},
    "hybrid": {"kind": "hybrid", "fields": {
        "geometry": {"kind": "cp", "aabb": box, "cell_size": [0.3, 0.1], "channels": 4, "rank": 2},
        "appearance": {"kind": "six_axis", "aabb": box, "cell_size": [0.3, 0.15], "channels": 4, "rank": 2}}},
}
lo, hi = torch.tensor(box).T
out = {}
for name, spec in specs.items():
    torch.manual_seed(0)
    field = tdfields.build(spec)
    x = (lo + (hi - lo) * torch.rand(64, 3)).requires_grad_(True)
    results = {}
    for backend in ("auto", "torch"):
        field.zero_grad()
        x.grad = None
        with kernels.use_backend(backend):
            y = field(x)
            y = torch.cat(list(y.values()), -1) if isinstance(y, dict) else y
            (y.square().sum() + y.sum()).backward()
        grads = [p.grad.clone() for p in field.parameters()] + [x.grad.clone()]
        results[backend] = (y.detach(), grads)
    (ya, ga), (yt, gt) = results["auto"], results["torch"]
    assert ya.shape[:-1] == (64,) and torch.isfinite(ya).all(), name
    torch.testing.assert_close(ya, yt, rtol=1e-5, atol=1e-6)
    for a, b in zip(ga, gt):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    assert float(gt[-1].abs().sum()) > 0, f"{name}: no gradient to the coordinates"
    out[name] = {"channels": ya.shape[-1], "parameters": sum(p.numel() for p in field.parameters())}
out["numba"] = kernels.numba_available()
print(json.dumps(out))
'''


class CheckFailed(RuntimeError):
    pass


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)


def _must(cmd, what: str, **kw) -> subprocess.CompletedProcess:
    r = _run(cmd, **kw)
    if r.returncode != 0:
        raise CheckFailed(f"{what} failed (exit {r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return r


def expected_members() -> tuple[set[str], set[str]]:
    """(package folders, preset files) the wheel must hold, as wheel paths, from the source tree."""
    packages, presets = set(), set()
    for top in ("tdfields", "slam"):
        for py in (ROOT / top).rglob("*.py"):
            rel = py.parent.relative_to(ROOT)
            if "__pycache__" not in rel.parts:
                packages.add(rel.as_posix())
    for yaml_file in (ROOT / "slam" / "configs").rglob("*.yaml"):
        presets.add(yaml_file.relative_to(ROOT).as_posix())
    return packages, presets


def check_wheel_contents(wheel: Path) -> dict:
    names = set(zipfile.ZipFile(wheel).namelist())
    packages, presets = expected_members()
    no_init = sorted(p for p in packages if f"{p}/__init__.py" not in names)
    if no_init:
        raise CheckFailed(f"{wheel.name}: packages missing from the wheel (no __init__.py there): {no_init}")
    sources = {py.relative_to(ROOT).as_posix() for top in ("tdfields", "slam") for py in (ROOT / top).rglob("*.py")
               if "__pycache__" not in py.parts}
    if sources - names:
        raise CheckFailed(f"{wheel.name}: modules missing from the wheel: {sorted(sources - names)}")
    if presets - names:
        raise CheckFailed(f"{wheel.name}: presets missing from the wheel: {sorted(presets - names)}")
    stray = sorted({n.split("/")[0] for n in names} - {"tdfields", "slam"} - {n.split("/")[0] for n in names
                                                                              if ".dist-info/" in n})
    if stray:
        raise CheckFailed(f"{wheel.name}: unexpected top-level entries: {stray}")
    meta = next(n for n in names if n.endswith(".dist-info/METADATA"))
    requires = [ln.split(":", 1)[1].strip() for ln in zipfile.ZipFile(wheel).read(meta).decode().splitlines()
                if ln.startswith("Requires-Dist:")]
    core = sorted(re.split(r"[<>=!~ ;]", r, maxsplit=1)[0].lower() for r in requires if "extra ==" not in r)
    if core != ["numba", "numpy", "pyyaml", "torch"]:
        raise CheckFailed(f"{wheel.name}: core requirements are {core}, expected numba, numpy, pyyaml, torch")
    return {"packages": len(packages), "modules": len(sources), "presets": len(presets)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep", type=Path, default=None, help="work folder to keep (default: a temporary one)")
    ap.add_argument("--fresh-kernel-cache", action="store_true", help="compile the fused kernels anew")
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="tdfields-wheel-"))
    work.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PYTHONNOUSERSITE": "1"}
    env.pop("PYTHONPATH", None)
    times = {}
    t_all = t = time.perf_counter()
    try:
        dist = work / "dist"
        _must([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", ROOT, "-w", dist], "building the wheel",
              env=env, cwd=work)
        wheel = next(dist.glob("tdfields-*.whl"), None)
        if wheel is None:
            raise CheckFailed(f"pip wheel wrote no tdfields-*.whl into {dist}")
        counts = check_wheel_contents(wheel)
        times["build + contents"] = time.perf_counter() - t
        print(f"wheel {wheel.name}: {counts['packages']} packages, {counts['modules']} modules, "
              f"{counts['presets']} presets, core requirements numba numpy pyyaml torch", flush=True)

        t = time.perf_counter()
        venv = work / "venv"
        _must([sys.executable, "-m", "venv", "--clear", venv], "creating the virtual environment", env=env)
        py = venv / ("Scripts" if os.name == "nt" else "bin") / "python"
        _must([py, "-m", "pip", "install", "-q", "--no-compile", TORCH], f"installing {TORCH}", env=env, cwd=work)
        times["venv + torch"] = time.perf_counter() - t

        t = time.perf_counter()
        _must([py, "-m", "pip", "install", "-q", "--no-compile", wheel], "installing the wheel without extras",
              env=env, cwd=work)
        listed = _must([py, "-m", "pip", "list", "--format=freeze"], "pip list", env=env, cwd=work).stdout
        installed = {ln.split("==")[0].lower() for ln in listed.splitlines() if "==" in ln}
        came_along = sorted(set(SLAM_SIDE) & installed)
        if came_along:
            raise CheckFailed(f"the wheel without extras installed SLAM-side packages: {came_along}")
        times["wheel install"] = time.perf_counter() - t
        print(f"installed without extras: {len(installed)} distributions, none of {', '.join(SLAM_SIDE)}",
              flush=True)

        t = time.perf_counter()
        probe_env = {**env, "OMP_NUM_THREADS": "1"}
        if args.fresh_kernel_cache:
            probe_env["TDFIELDS_CACHE_DIR"] = str(work / "kernel-cache")
        r = _must([py, "-c", PROBE], "building and querying every kind", env=probe_env, cwd=work)
        times["every kind, fused vs reference"] = time.perf_counter() - t
        print(f"every kind builds, queries and back-propagates: {r.stdout.strip()}", flush=True)

        t = time.perf_counter()
        r = _run([py, "-c", "import slam"], env=env, cwd=work)
        message = ('the SLAM client (slam, lrslam) needs ' + ", ".join(
            ["trimesh", "scikit-image", "scipy", "tqdm", "matplotlib", "imageio"])
            + ', not installed (tdfields alone does not); install the slam extra: '
              'python3 -m pip install "tdfields[slam]"')
        last = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
        if r.returncode == 0 or last != f"slam.errors.MissingDependencyError: {message}":
            raise CheckFailed(f"import slam without the slam extra: exit {r.returncode}, stderr:\n{r.stderr}")
        lrslam = py.parent / ("lrslam.exe" if os.name == "nt" else "lrslam")
        r = _run([lrslam, "run"], env=env, cwd=work)
        if r.returncode != 2 or r.stderr != f"lrslam: error: {message}\n" or r.stdout:
            raise CheckFailed(f"lrslam without the slam extra: exit {r.returncode}, stdout {r.stdout!r}, "
                              f"stderr {r.stderr!r}")
        times["import slam / lrslam"] = time.perf_counter() - t
        print(f"import slam and lrslam without the extra: one line, exit 2 ({message})", flush=True)
    except CheckFailed as exc:
        print(f"check_wheel: error: {exc}", file=sys.stderr)
        return 1
    finally:
        steps = ", ".join(f"{k} {v:.0f} s" for k, v in times.items())
        print(f"check_wheel: {time.perf_counter() - t_all:.0f} s ({steps})", flush=True)
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print("check_wheel: ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
