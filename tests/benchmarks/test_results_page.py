"""benchmarks/results_page.py and the curated benchmarks folder: docs/results.md is what the committed JSON gives,
every result under benchmarks/results/ is cited by a docs page, and every script explains itself with --help."""

import re
from pathlib import Path

import pytest

from tests.benchmarks.conftest import BENCHMARKS, script_on_path

ROOT = BENCHMARKS.parent
#: scripts whose toy-size run is CI's `bash benchmarks/gpu_check.sh --smoke` (.ci/run), not a test module here
SMOKE = {"gpu_check", "slam_compare", "gn_convergence", "test_field_speed"}


def scripts() -> list[str]:
    return sorted(p.stem for p in BENCHMARKS.glob("*.py") if not p.stem.startswith("_") and p.stem != "conftest")


def test_the_results_page_is_what_the_committed_json_gives():
    with script_on_path("results_page") as page:
        assert page.main(["--check"]) == 0, "docs/results.md is stale: run python benchmarks/results_page.py"


def test_every_result_is_cited_by_a_docs_page():
    docs = "\n".join(p.read_text() for p in [*(ROOT / "docs").glob("*.md"), ROOT / "README.md"])
    docs += (BENCHMARKS / "results_page.py").read_text()  # what the generated page will cite
    def cited(name: str) -> bool:
        return bool(re.search(rf"results/{re.escape(name)}(?![\w-]|\.\w)", docs))

    # a file beside a cited one of the same stem (memory_growth.csv, .png beside memory_growth.json) goes with it
    uncited = [p.name for p in (BENCHMARKS / "results").iterdir() if not p.name.startswith(".")
               and not cited(p.name) and not (p.is_file() and cited(p.stem + ".json"))]
    assert not uncited, f"results no docs page cites (delete them or cite them): {uncited}"


@pytest.mark.parametrize("name", scripts())
def test_every_script_has_help_and_a_toy_size_test(name, capsys):
    if name != "test_field_speed":  # a pytest module: its --help is pytest's
        with script_on_path(name) as script, pytest.raises(SystemExit) as done:
            script.main(["--help"])
        assert done.value.code == 0
        assert len(capsys.readouterr().out.splitlines()) > 3
    assert name in SMOKE or (ROOT / "tests" / "benchmarks" / f"test_{name}.py").exists() \
        or name in {"induced_loss"} and (ROOT / "tests" / "benchmarks" / "test_no_depth_study.py").exists()


def test_the_folder_stays_curated():
    assert len(scripts()) <= 22, "benchmarks/ holds the scripts behind published numbers; retire one-off experiments"
