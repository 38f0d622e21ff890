"""Record an Intel RealSense (D400 / L500 series) into the TUM layout that ``lrslam run`` reads.

    python3 -m pip install -e ".[realsense]"
    python examples/record_realsense.py --out data/my_desk --frames 600        # 20 s at 30 Hz; Ctrl-C stops early
    lrslam run --config tum --data data/my_desk --out runs/my_desk

Depth is aligned to the colour camera on the host (``rs.align``), so one camera model, the colour stream's
intrinsics as the device reports them, serves both; it goes into ``calibration.yaml`` with the depth scale
(``1 / depth_units``, 1000 on most models). The folder layout is written by :class:`slam.data.TUMWriter`
(tested there); this script only talks to the camera. There is no ground truth: ``lrslam run`` tracks and
maps, and reports no ATE. See docs/data.md ("Recording your own sequence").
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def intrinsics_of(stream_profile):
    """``(Intrinsics, distortion or None)`` of a RealSense video stream profile."""
    import pyrealsense2 as rs

    from slam.data import Intrinsics

    k = stream_profile.as_video_stream_profile().get_intrinsics()
    intr = Intrinsics(float(k.fx), float(k.fy), float(k.ppx), float(k.ppy), int(k.height), int(k.width))
    coeffs = [float(c) for c in k.coeffs]
    if not any(coeffs):
        return intr, None
    if k.model == rs.distortion.brown_conrady:  # OpenCV's model and order: k1 k2 p1 p2 k3
        return intr, coeffs
    # inverse Brown-Conrady (some colour sensors) maps the other way; the loader's undistortion does not
    print(f"record_realsense: warning: the colour stream's {k.model} distortion {coeffs} is not written "
          "(the loader undistorts Brown-Conrady only); images are used as they are", file=sys.stderr)
    return intr, None


def record(out: str, frames: int, width: int, height: int, fps: int, warmup: int) -> int:
    import pyrealsense2 as rs

    from slam.data import TUMWriter

    pipeline, config = rs.pipeline(), rs.config()
    config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
    config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
    profile = pipeline.start(config)
    try:
        depth_units = profile.get_device().first_depth_sensor().get_depth_scale()  # metres per raw unit
        intr, dist = intrinsics_of(profile.get_stream(rs.stream.color))
        align = rs.align(rs.stream.color)
        for _ in range(warmup):  # auto-exposure settles
            pipeline.wait_for_frames()
        n, last = 0, -np.inf
        with TUMWriter(out, intr, distortion=dist, depth_scale=1.0 / depth_units) as rec:
            try:
                while frames <= 0 or n < frames:
                    fs = align.process(pipeline.wait_for_frames())
                    color, depth = fs.get_color_frame(), fs.get_depth_frame()
                    if not color or not depth or color.get_timestamp() / 1000.0 <= last:
                        continue
                    t = color.get_timestamp() / 1000.0  # ms -> s
                    rec.add(t, np.asanyarray(color.get_data()), np.asanyarray(depth.get_data()),
                            depth_timestamp=depth.get_timestamp() / 1000.0)
                    n, last = n + 1, t
                    if n % 30 == 0:
                        print(f"\r{n} frames", end="", file=sys.stderr, flush=True)
            except KeyboardInterrupt:
                pass
    finally:
        pipeline.stop()
    print(f"\nrecorded {n} frames into {out} ({intr.width}x{intr.height}, fx={intr.fx:.1f}, "
          f"depth scale {1.0 / depth_units:g})", file=sys.stderr)
    return 0 if n else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="new folder for the recording")
    ap.add_argument("--frames", type=int, default=0, help="frames to record (0: until Ctrl-C)")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--fps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=30, help="frames dropped first, while auto-exposure settles")
    args = ap.parse_args(argv)
    try:
        import pyrealsense2  # noqa: F401
    except ImportError:
        print('record_realsense: error: pyrealsense2 is not installed: python3 -m pip install -e ".[realsense]"',
              file=sys.stderr)
        return 2
    from slam.errors import SlamInputError

    try:
        return record(args.out, args.frames, args.width, args.height, args.fps, args.warmup)
    except SlamInputError as exc:
        print(f"record_realsense: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # librealsense: no device, stream not supported, ...
        print(f"record_realsense: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
