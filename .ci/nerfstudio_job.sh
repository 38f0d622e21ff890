#!/usr/bin/env bash
# The nerfstudio plugin's job (docs/nerf.md, "nerfstudio plugin"): a virtual environment that sees the system's
# packages (torch 2.13.0+cpu and the project's dependencies), nerfstudio 1.1.5 and exactly the packages `ns-train`
# imports, all without their dependencies (nerfstudio's own would pull torchvision and another torch), this
# package installed into it, and then the nerfstudio test alone. About 75 s here with pip's cache warm.
#
#   bash .ci/nerfstudio_job.sh [VENV]      # default: a fresh folder under $TMPDIR, removed at the end
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1

KEEP=${1:-}
VENV=${KEEP:-$(mktemp -d)/nsvenv}
[ -n "$KEEP" ] || trap 'rm -rf "$(dirname "$VENV")"' EXIT

# keep in step with the recipe in docs/nerf.md
PACKAGES=(
    nerfstudio==1.1.5
    # nerfstudio's encodings and scene box (viser's server imports msgspec, rich, websockets)
    jaxtyping==0.3.11 viser==0.2.7 msgspec==0.23.0 rich==15.0.0 websockets==17.4
    # ns-train's command line (tyro 0.9 changed the API nerfstudio 1.1.5 uses)
    tyro==0.8.14 docstring-parser==0.16 shtab==1.7.1
    # imported at module level by the modules ns-train loads (cameras, writer, data parsers, data managers,
    # the other methods' models, the viewer), though the tdfields methods never call them
    opencv-python-headless==4.10.0.84 tensorboard==2.21.0 absl-py==2.1.0 appdirs==1.4.4 rawpy==0.24.0
    pyquaternion==0.9.9 fpsample==1.0.2 pathos==0.3.3 ppft==1.7.6.9 dill==0.3.9 pox==0.3.5 multiprocess==0.70.17
    gsplat==1.4.0 pytorch-msssim==1.0.0 tensorly==0.9.0 splines==0.3.0 nerfacc==0.5.2
)

t0=$(date +%s)
python3 -m venv --system-site-packages "$VENV"
PY="$VENV/bin/python"
"$PY" -m pip install -q --no-deps "${PACKAGES[@]}"
# nerfstudio 1.1.5 imports torchvision at the top of its pipeline module for one call (saving images in
# `ns-eval --render-output-path`), and no torchvision imports beside a CPU-only torch 2.13: make that import lazy
"$PY" - <<'EOF'
import importlib.util
import pathlib

package = pathlib.Path(importlib.util.find_spec("nerfstudio").submodule_search_locations[0])
path = package / "pipelines" / "base_pipeline.py"
text = path.read_text()
old_import, old_call = "\nimport torchvision.utils as vutils\n", "vutils.save_image("
lazy_call = '__import__("torchvision.utils").utils.save_image('
if old_import in text:
    assert text.count(old_import) == 1 and text.count(old_call) == 1, f"{path}: not nerfstudio 1.1.5's"
    path.write_text(text.replace(old_import, "\n").replace(old_call, lazy_call))
EOF
# the package itself, so its nerfstudio.method_configs entry points are registered in the venv
"$PY" -m pip install -q --no-deps -e .
TORCH=$("$PY" -c 'import torch; print(torch.__version__)')
echo "nerfstudio venv ready in $(( $(date +%s) - t0 )) s: $VENV (torch $TORCH)"

"$PY" -m pytest -q -n 0 -p no:cacheprovider tests/tdfields/integrations/test_nerfstudio.py
echo "nerfstudio job: $(( $(date +%s) - t0 )) s"
