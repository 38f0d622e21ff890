#!/usr/bin/env bash
# The prepared GPU check (benchmarks/gpu_check.py): on a lent GPU machine, from the repository root,
#   bash benchmarks/gpu_check.sh --data shared/data/tum_fr1_rpy --out "$OUT"
# and anywhere, on the CPU at toy sizes (CI runs this):
#   bash benchmarks/gpu_check.sh --smoke --out /tmp/gpu_smoke
# Python packages the GPU image lacks (trimesh for `import slam`) travel as wheels in .whl/ (see docs/benchmarks.md).
set -euo pipefail
cd "$(dirname "$0")/.."
if compgen -G ".whl/*.whl" > /dev/null; then
  # a fresh folder: a fixed one (it was /tmp/site) can hold anything, e.g. a built mkdocs site whose tdfields/
  # page folder shadowed the package
  site=$(mktemp -d)
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$site" .whl/*.whl
  export PYTHONPATH=$site${PYTHONPATH:+:$PYTHONPATH}
fi
exec python3 benchmarks/gpu_check.py "$@"
