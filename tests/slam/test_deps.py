"""The slam extra: tdfields installs alone; without the SLAM packages `import slam` and `lrslam` say so in one line."""

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from slam import _deps
from slam.cli import main

ROOT = Path(__file__).resolve().parents[2]
COMMAND = f'python3 -m pip install -e "{ROOT}[slam]"'


def _pyproject():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _names(requirements):
    return {re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].lower() for r in requirements}


def test_core_dependencies_are_what_tdfields_imports_and_slam_extra_matches_the_check():
    project = _pyproject()["project"]
    assert _names(project["dependencies"]) == {"torch", "numpy", "numba", "pyyaml"}
    slam_extra = _names(project["optional-dependencies"]["slam"])
    # embreex is installed by the extra but optional at run time (slam.eval falls back to trimesh's ray caster)
    assert slam_extra - {"embreex"} == set(_deps.SLAM_REQUIREMENTS.values())
    assert "tdfields" in _names(project["optional-dependencies"]["dev"])  # dev pulls the slam extra
    assert project["scripts"]["lrslam"] == "slam.cli:main"
    # every package tdfields imports at module level is a core dependency
    imported = set()
    for path in (ROOT / "tdfields").rglob("*.py"):
        if "integrations" in path.relative_to(ROOT).parts:
            continue  # adapters import their library (an extra) themselves; `import tdfields` imports none of them
        for m in re.finditer(r"^\s*(?:import|from)\s+([A-Za-z_]\w*)", path.read_text(), re.M):
            imported.add(m.group(1))
    third_party = {name for name in imported if name not in sys.stdlib_module_names} - {"tdfields"}
    # triton: the optional GPU kernel, loaded lazily (tdfields.kernels)
    assert third_party == {"torch", "numpy", "numba", "yaml", "triton"}
    assert "nerfstudio" in _names(project["optional-dependencies"]["nerfstudio"])


def _fake_find_spec(missing):
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        return None if name in missing else real(name, *args, **kwargs)

    return find_spec


def test_missing_dependencies_and_the_one_line_message(monkeypatch):
    assert _deps.missing_dependencies() == []
    monkeypatch.setattr(importlib.util, "find_spec", _fake_find_spec({"skimage", "trimesh"}))
    assert _deps.missing_dependencies() == ["trimesh", "scikit-image"]
    assert _deps.install_command() == COMMAND
    assert _deps.missing_message(["trimesh", "scikit-image"]) == (
        "the SLAM client (slam, lrslam) needs trimesh, scikit-image, not installed (tdfields alone does not); "
        f"install the slam extra: {COMMAND}"
    )


def test_cli_main_reports_missing_packages_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(importlib.util, "find_spec", _fake_find_spec({"scipy"}))
    assert main(["run", "--out", "never-written"]) == 2
    err = capsys.readouterr().err
    assert err == f"lrslam: error: the SLAM client (slam, lrslam) needs scipy, not installed (tdfields alone " \
                  f"does not); install the slam extra: {COMMAND}\n"
    assert not Path("never-written").exists()


def test_error_is_an_import_error_naming_the_package():
    from slam.errors import MissingDependencyError

    err = MissingDependencyError(["tqdm"])
    assert isinstance(err, ImportError) and err.name == "tqdm" and err.missing == ["tqdm"]
    assert "\n" not in str(err) and COMMAND in str(err)
    import pickle

    back = pickle.loads(pickle.dumps(err))  # e.g. from a worker process
    assert type(back) is MissingDependencyError and back.missing == ["tqdm"] and str(back) == str(err)


@pytest.mark.parametrize(("argv0", "orig", "expected"), [
    ("/venv/bin/lrslam", ["/venv/bin/python", "/venv/bin/lrslam", "run"], True),
    ("C:\\venv\\Scripts\\lrslam.exe", ["lrslam.exe"], True),
    ("/venv/bin/lrslam-script.py", ["python", "/venv/bin/lrslam-script.py"], True),
    ("-m", ["python3", "-m", "slam", "run"], True),
    ("-m", ["python3", "-X", "importtime", "-mslam"], True),
    ("-m", ["python3", "-m", "pytest", "-q"], False),
    ("-c", ["python3", "-c", "import slam"], False),
    ("train.py", ["python3", "train.py", "-m", "slam"], False),
])
def test_running_cli(monkeypatch, argv0, orig, expected):
    monkeypatch.setattr(sys, "argv", [argv0])
    monkeypatch.setattr(sys, "orig_argv", orig)
    assert _deps.running_cli() is expected


# --------------------------------------------------------------- real interpreters without a package
def _run(args, tmp_path, blocked="skimage"):
    """Run Python from the repository with ``blocked`` unimportable (sys.modules[name] = None, set by a
    sitecustomize before anything else runs)."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(f"import sys\nsys.modules[{blocked!r}] = None\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)


def test_import_slam_without_a_package_raises_one_line_import_error(tmp_path):
    r = _run(["-c", "import slam"], tmp_path)
    assert r.returncode == 1
    assert r.stderr.splitlines()[-1] == (
        "slam.errors.MissingDependencyError: the SLAM client (slam, lrslam) needs scikit-image, not installed "
        f"(tdfields alone does not); install the slam extra: {COMMAND}")
    r = _run(["-c", "import tdfields\ntry:\n    import slam.data\nexcept ImportError as e:\n    print(e.name)"],
             tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (0, "scikit-image\n", "")


@pytest.mark.parametrize("how", ["console-script", "-m"])
def test_lrslam_without_a_package_prints_one_line_and_exits_2(tmp_path, how):
    if how == "console-script":
        # what pip writes into bin/lrslam for `lrslam = "slam.cli:main"`
        script = tmp_path / "lrslam"
        script.write_text("import re\nimport sys\nfrom slam.cli import main\nif __name__ == '__main__':\n"
                          "    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])\n"
                          "    sys.exit(main())\n")
        args = [str(script), "run", "--help"]
    else:
        args = ["-m", "slam", "run"]
    r = _run(args, tmp_path, blocked="trimesh")
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == ("lrslam: error: the SLAM client (slam, lrslam) needs trimesh, not installed (tdfields "
                        f"alone does not); install the slam extra: {COMMAND}\n")
