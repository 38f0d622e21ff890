"""Camera calibration of a TUM-format folder recorded with any camera: ``calibration.yaml`` and loader options.

``calibration.yaml`` (what :mod:`slam.data.tum_writer` writes; every length in pixels, on the images as stored)::

    fx: 615.3          # focal lengths
    fy: 615.1
    cx: 319.8          # principal point (pixel centres at integer coordinates)
    cy: 241.2
    width: 640         # the image size the numbers are for: the depth images' size
    height: 480
    distortion: [0.12, -0.25, 0.0, 0.0, 0.1]   # optional: Brown-Conrady k1 k2 p1 p2 [k3] (OpenCV order)
    depth_scale: 1000  # optional: depth PNG value / depth_scale = metres (TUM's Kinect: 5000)

The same keys are accepted as loader options (``data.options`` in a config): ``intrinsics`` as a mapping
``{fx, fy, cx, cy[, width, height]}`` (the size defaults to the depth images'), ``distortion`` as a list,
``depth_scale`` as a number.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from slam.data.types import Intrinsics
from slam.errors import SlamInputError

__all__ = ["CALIBRATION_FILE", "Calibration", "read_calibration", "write_calibration", "parse_intrinsics",
           "parse_distortion", "parse_depth_scale"]

#: the file name a TUM-format folder may carry its camera in
CALIBRATION_FILE = "calibration.yaml"

_INTRINSIC_KEYS = ("fx", "fy", "cx", "cy", "width", "height")
_FILE_KEYS = set(_INTRINSIC_KEYS) | {"distortion", "depth_scale"}


@dataclass(frozen=True)
class Calibration:
    """A camera as read from a calibration file: intrinsics on the stored images, optional distortion
    ``(k1, k2, p1, p2, k3)`` and depth scale (raw / metres); ``path`` is the file it came from."""

    intrinsics: Intrinsics
    distortion: tuple[float, ...] | None
    depth_scale: float | None
    path: Path


# YAML 1.1 (PyYAML) reads exponent notation without a dot, "1e-5", as a string; it is the number it spells
_EXPONENT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def _number(value: Any, where: str, key: str) -> float:
    if isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SlamInputError(f"{where}: key '{key}' must be a number, got {value!r}")
    if not math.isfinite(value):
        raise SlamInputError(f"{where}: key '{key}' must be finite, got {value!r}")
    return float(value)


def _size(value: Any, where: str, key: str) -> int:
    v = _number(value, where, key)
    if v != int(v) or v < 1:
        raise SlamInputError(f"{where}: key '{key}' must be a positive whole number of pixels, got {value!r}")
    return int(v)


def parse_intrinsics(value: Any, where: str, image_size: tuple[int, int] | None = None) -> Intrinsics:
    """Intrinsics from an :class:`Intrinsics` or a mapping ``{fx, fy, cx, cy[, width, height]}``.

    Args:
        value: the option or file content.
        where: what to name in errors (a file, or ``"option 'intrinsics'"``).
        image_size: ``(height, width)`` used when the mapping has no size; None: the size is required.
    """
    if isinstance(value, Intrinsics):
        return value
    if not isinstance(value, Mapping):
        raise SlamInputError(f"{where}: expected a mapping with keys fx, fy, cx, cy, width, height, got {value!r}")
    unknown = sorted(set(value) - set(_INTRINSIC_KEYS))
    if unknown:
        raise SlamInputError(f"{where}: unknown key '{unknown[0]}' (intrinsics keys: {', '.join(_INTRINSIC_KEYS)})")
    required = _INTRINSIC_KEYS if image_size is None else _INTRINSIC_KEYS[:4]
    for key in required:
        if key not in value:
            raise SlamInputError(f"{where}: missing key '{key}' (needs {', '.join(required)})")
    fx, fy, cx, cy = (_number(value[k], where, k) for k in ("fx", "fy", "cx", "cy"))
    for key, v in (("fx", fx), ("fy", fy)):
        if v <= 0:
            raise SlamInputError(f"{where}: key '{key}' must be positive, got {v}")
    if ("width" in value) != ("height" in value):
        raise SlamInputError(f"{where}: give both 'width' and 'height' or neither")
    if "width" in value:
        height, width = _size(value["height"], where, "height"), _size(value["width"], where, "width")
    else:
        height, width = image_size
    return Intrinsics(fx, fy, cx, cy, height, width)


def parse_distortion(value: Any, where: str) -> tuple[float, ...] | None:
    """``(k1, k2, p1, p2[, k3])`` from a list of 4 or 5 numbers; None or an empty list: no distortion."""
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) not in (0, 4, 5):
        raise SlamInputError(f"{where}: key 'distortion' must be a list [k1, k2, p1, p2, k3] (4 or 5 numbers), "
                             f"got {value!r}")
    coeffs = tuple(_number(v, where, f"distortion[{i}]") for i, v in enumerate(value))
    return coeffs if any(coeffs) else None


def parse_depth_scale(value: Any, where: str) -> float:
    scale = _number(value, where, "depth_scale")
    if scale <= 0:
        raise SlamInputError(f"{where}: key 'depth_scale' must be positive (raw value / scale = metres), got {scale}")
    return scale


def read_calibration(path: str | Path) -> Calibration:
    """Read a ``calibration.yaml`` (module docstring); SlamInputError naming the file and key if it is bad."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise SlamInputError(f"{path}: calibration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    except yaml.YAMLError as exc:
        raise SlamInputError(f"{path}: invalid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(data, dict):
        raise SlamInputError(f"{path}: expected a mapping with keys {', '.join(_INTRINSIC_KEYS)}, got "
                             f"{type(data).__name__}")
    unknown = sorted(set(data) - _FILE_KEYS)
    if unknown:
        raise SlamInputError(f"{path}: unknown key '{unknown[0]}' (keys: {', '.join(sorted(_FILE_KEYS))})")
    where = str(path)
    intr = parse_intrinsics({k: data[k] for k in _INTRINSIC_KEYS if k in data}, where)
    dist = parse_distortion(data.get("distortion"), where)
    scale = parse_depth_scale(data["depth_scale"], where) if data.get("depth_scale") is not None else None
    return Calibration(intr, dist, scale, path)


def write_calibration(path: str | Path, intrinsics: Intrinsics, distortion: Sequence[float] | None = None,
                      depth_scale: float | None = None) -> Path:
    """Write ``calibration.yaml`` for ``intrinsics`` (and distortion, depth scale); returns the path."""
    import yaml

    data: dict[str, Any] = {"fx": float(intrinsics.fx), "fy": float(intrinsics.fy), "cx": float(intrinsics.cx),
                            "cy": float(intrinsics.cy), "width": int(intrinsics.width),
                            "height": int(intrinsics.height)}
    if distortion is not None and any(distortion):
        data["distortion"] = [float(d) for d in distortion]
    if depth_scale is not None:
        data["depth_scale"] = float(depth_scale)
    def scalar(v):  # YAML's own spelling: 1.0e-05, not 1e-05, which YAML 1.1 would read as a string
        return yaml.safe_dump(v).splitlines()[0]

    lines = ["# camera of the rgb images (depth is registered to them), pixels on the images as stored;",
             "# distortion: Brown-Conrady k1 k2 p1 p2 k3 (OpenCV order); depth PNG value / depth_scale = metres"]
    for key, value in data.items():
        text = "[" + ", ".join(scalar(v) for v in value) + "]" if isinstance(value, list) else scalar(value)
        lines.append(f"{key}: {text}")
    text = "\n".join(lines) + "\n"
    path = Path(path)
    path.write_text(text)
    return path
