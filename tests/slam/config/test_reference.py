"""The configuration reference (docs/configuration.md) documents every key of the schema and is current."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path
from typing import get_type_hints

import pytest

from slam.config import Config, load_config
from slam.config.dotted import flatten
from slam.config.reference import PAGE, SCRIPT, render_reference, schema_keys, value_text
from slam.errors import SlamInputError

ROOT = Path(__file__).resolve().parents[3]


def _rows(text: str) -> dict[str, list[str]]:
    """The key tables' rows of the page: dotted key -> its cells (type, default, range / choices, meaning)."""
    rows = {}
    for line in text.splitlines():
        m = re.match(r"^\| `([\w.]+)` \| (.*) \|$", line)
        if m:
            rows[m.group(1)] = [c.strip() for c in re.split(r"(?<!\\)\|", m.group(2))]
    return rows


def test_every_key_has_a_line_of_meaning():
    keys = schema_keys()
    undocumented = [k.key for k in keys if not k.doc.strip()]
    assert undocumented == [], f"keys without a doc= line in slam/config/schema/: {undocumented}"
    # every key of a resolved config is in the reference once, and nothing else
    leaves = [k.key for k in keys if not k.group]
    assert sorted(leaves) == sorted(flatten(Config().to_dict()))


def test_every_section_has_its_introduction():
    hints = get_type_hints(Config)
    sections = [f for f in dataclasses.fields(Config) if dataclasses.is_dataclass(hints[f.name])]
    assert len(sections) == 10 and all(f.metadata.get("doc") for f in sections)


def test_the_committed_page_is_current():
    page = ROOT / PAGE
    assert page.is_file(), f"{PAGE} is missing: run python {SCRIPT}"
    assert page.read_text() == render_reference(), f"{PAGE} is stale: run python {SCRIPT}"


def test_the_script_check_passes_on_the_committed_page():
    out = subprocess.run([sys.executable, str(ROOT / SCRIPT), "--check"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


@pytest.mark.parametrize("key, default, allowed", [
    ("tracking.iters", "8", ">= 1 and <= 10000000"),
    ("rendering.color_cutoff", "0.0", ">= 0 and < 1"),
    ("appearance.kind", "six_axis", "`cp`, `dense_grid`, `six_axis`, `triplane`, `vector_matrix`"),
    ("mapping.weights.depth", "0.1", ">= 0 and <= 10000000"),
    ("scene.grow", "auto", "`auto`, `true`, `false`"),
])
def test_a_row_holds_the_schema_default_and_range(key, default, allowed):
    rows = _rows((ROOT / PAGE).read_text())
    assert rows[key][1] == f"`{default}`" and rows[key][2] == allowed


def test_every_row_matches_the_schema():
    rows = _rows(render_reference())
    defaults = flatten(Config().to_dict())
    for k in schema_keys():
        if k.group:
            continue
        assert rows[k.key][1] == f"`{value_text(defaults[k.key])}`", k.key
        assert rows[k.key][2] == k.allowed, k.key


def test_the_ranges_printed_are_the_ones_checked():
    # a value just past a printed bound is refused as the config is read
    rows = _rows(render_reference())
    for key in ("tracking.pixels", "mapping.need_loss_factor", "data.prefetch"):
        lo = float(re.match(r">=? ([\d.]+)", rows[key][2]).group(1))
        with pytest.raises(SlamInputError, match=key):
            load_config("synthetic", [f"{key}={lo - 1}"], profile="quality")


def test_the_layer_table_lists_every_bundled_file():
    from slam.config.presets import list_presets
    from slam.config.profiles import ALIASES, PROFILES

    text = render_reference()
    for name in list_presets() + list(ALIASES):
        assert f"| `--config {name}` |" in text
    for name in PROFILES:
        assert f"| `--profile {name}` |" in text
    assert "| `--profile realtime` |" in text and "`mapping.schedule=by_need`" in text
