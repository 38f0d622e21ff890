#!/usr/bin/env bash
# The screenshot in docs/viewer.md: the TUM excerpt run logged with --rerun, opened in Rerun's native viewer on a
# virtual X display (Xvfb) with Mesa's software Vulkan (lavapipe), which saves a screenshot and quits.
#   apt-get install -y xvfb xdotool mesa-vulkan-drivers libvulkan1      (no GPU or display needed)
# Usage: [RRD=FILE.rrd] docs/scripts/viewer_screenshot.sh [DATA] [OUT_PNG]
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=${1:-../shared/data/tum_fr1_rpy}
PNG=${2:-docs/images/viewer_tum.png}
WORK=$(mktemp -d)
# RRD=FILE: reuse that recording if it exists, else keep the new one there
if [ -n "${RRD:-}" ] && [ -f "$RRD" ]; then
  cp "$RRD" "$WORK/tum.rrd"
else
  python -m slam.cli run --config tum/fr1_rpy-cpu --data "$DATA" --out "$WORK/run" --quiet --rerun "$WORK/tum.rrd"
  if [ -n "${RRD:-}" ]; then cp "$WORK/tum.rrd" "$RRD"; fi
fi
Xvfb :97 -screen 0 1600x900x24 >/dev/null 2>&1 &
XPID=$!
trap 'kill $XPID; rm -rf "$WORK"' EXIT
sleep 2
# keep the pointer in a corner while the viewer starts and renders: no hover tooltips in the picture
(for _ in $(seq 120); do DISPLAY=:97 xdotool mousemove 1599 899 2>/dev/null || true; sleep 0.5; done) &
MPID=$!
trap 'kill $XPID $MPID 2>/dev/null; rm -rf "$WORK"' EXIT
DISPLAY=:97 XDG_RUNTIME_DIR=$WORK rerun "$WORK/tum.rrd" --window-size 1600x900 --screenshot-to "$WORK/shot.png"
# the viewer renders at twice the logical size; half of it is plenty for the docs
python - "$WORK/shot.png" "$PNG" <<'PY'
import sys
from PIL import Image
im = Image.open(sys.argv[1]).convert("RGB")
im.resize((im.width // 2, im.height // 2), Image.LANCZOS).save(sys.argv[2], optimize=True)
print(f"{sys.argv[2]}: {im.width // 2}x{im.height // 2}")
PY
