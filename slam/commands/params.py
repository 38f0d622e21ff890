"""``lrslam params``: Table-1 style parameter counts and growth of a preset's scene (from tdfields.report)."""

from __future__ import annotations

import json
from pathlib import Path

from slam.errors import SlamInputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "params",
        help="parameter counts and complexity of a preset's scene representation",
        description=(
            "Build a preset's scene (fields + decoders) and print tdfields.report's per-field table plus the "
            "geometry / appearance / decoders / total split. Needs an explicit scene bound (bound=auto depends "
            "on data; pass bound=[[x0,x1],[y0,y1],[z0,z1]])."
        ),
    )
    p.add_argument("--config", default="replica/room0", help="preset name or YAML (default: replica/room0)")
    p.add_argument("--json", default=None, metavar="OUT", help="also write the counts as JSON to OUT")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides, e.g. representation=eslam")
    p.set_defaults(func=main, overrides_anywhere=True)


def _m(n: int) -> str:
    return f"{n / 1e6:.2f}M"


def main(args) -> int:
    import tdfields
    from slam.config import load_config
    from slam.model.scene import SceneModel, parameter_counts, scene_aabb

    cfg = load_config(args.config, args.overrides)
    if cfg.scene.bound == "auto":
        raise SlamInputError(
            f"preset '{cfg.name}' has bound=auto (estimated from data); pass bound=[[x0,x1],[y0,y1],[z0,z1]]"
        )
    aabb = scene_aabb(cfg.scene.bound, cfg.scene.bound_dividable)
    model = SceneModel(cfg, aabb)
    counts = parameter_counts(model)
    ext = (aabb[:, 1] - aabb[:, 0]).tolist()
    print(f"preset {cfg.name}  representation {cfg.representation}  "
          f"(geometry {cfg.geometry.kind}, appearance {cfg.appearance.kind})")
    print(f"enlarged bound {[[round(a, 4), round(b, 4)] for a, b in aabb.tolist()]}  "
          f"extents {' x '.join(f'{e:.2f}' for e in ext)} m")
    print(tdfields.report(model))
    print()
    print(f"{'geometry':<12}{counts['geometry']:>14,}  {_m(counts['geometry'])}")
    print(f"{'appearance':<12}{counts['appearance']:>14,}  {_m(counts['appearance'])}")
    print(f"{'decoders':<12}{counts['decoders']:>14,}")
    print(f"{'total':<12}{counts['total']:>14,}  {_m(counts['total'])}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(counts, indent=2))
    return 0
