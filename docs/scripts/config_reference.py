"""Write the configuration reference, docs/configuration.md, from the schema (run from anywhere).

    python docs/scripts/config_reference.py            # rewrite the page
    python docs/scripts/config_reference.py --check    # exit 1 when the page is stale, 0 when it is current

The page is :func:`slam.config.reference.render_reference`: every key's type, default, range and meaning from
``slam/config/schema/``, and what each preset, profile and representation block sets from ``slam/configs/``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from slam.config.reference import PAGE, render_reference  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="only compare: exit 1 when the page is stale")
    args = p.parse_args(argv)
    page, text = ROOT / PAGE, render_reference()
    current = page.read_text() if page.is_file() else None
    if args.check:
        if current != text:
            print(f"{PAGE} is stale: run python docs/scripts/config_reference.py", file=sys.stderr)
            return 1
        print(f"{PAGE} is current")
        return 0
    if current != text:
        page.write_text(text)
        print(f"wrote {PAGE} ({text.count(chr(10))} lines)")
    else:
        print(f"{PAGE} is current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
