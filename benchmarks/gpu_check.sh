#!/usr/bin/env bash
# The prepared GPU check (benchmarks/gpu_check.py): on a lent GPU machine, from the repository root,
#   bash benchmarks/gpu_check.sh --data shared/data/tum_fr1_rpy --out "$OUT"
# and anywhere, on the CPU at toy sizes (CI runs this):
#   bash benchmarks/gpu_check.sh --smoke --out /tmp/gpu_smoke
# Python packages the GPU image lacks (trimesh for `import slam`) travel as wheels in .whl/ (see docs/benchmarks.md).
set -euo pipefail
cd "$(dirname "$0")/.."
if compgen -G ".whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
exec python3 benchmarks/gpu_check.py "$@"
