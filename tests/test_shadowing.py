"""The ``magfit`` command works where pymavlink's ``magfit.py`` script sits in the same ``bin/``.

A console script runs with its own folder first on ``sys.path``: there ``import magfit`` finds pymavlink's
script, not the package. The command's entry point (``_magfit_entry``) takes such folders off the path first.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

import magfit

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

#: What pip writes as bin/magfit for the entry point "module:main" (the form of pip's console-script template).
CONSOLE_SCRIPT = """\
import re
import sys
from {module} import main
if __name__ == '__main__':
    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])
    sys.exit(main())
"""

#: A stand-in for pymavlink's bin/magfit.py: importing it as ``magfit`` says so and stops.
SHADOW = "import sys\nprint('pymavlink magfit.py ran')\nsys.exit(7)\n"


def _clean_environment() -> dict[str, str]:
    """The environment without PYTHONPATH and friends: the subprocess sees only what its interpreter has."""
    return {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}


def _run(
    arguments: list[str | Path], cwd: Path, env: dict[str, str], timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(a) for a in arguments], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )


def test_the_entry_point_skips_a_magfit_py_beside_the_script(tmp_path: Path) -> None:
    # The checkout's source, and a bin/ that holds both the console script and a magfit.py.
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "magfit.py").write_text(SHADOW, encoding="utf-8")
    env = {**_clean_environment(), "PYTHONPATH": str(SRC)}
    # The control: the entry point the command had before, magfit.cli:main, runs the other script.
    (bin_dir / "magfit_before").write_text(CONSOLE_SCRIPT.format(module="magfit.cli"), encoding="utf-8")
    before = _run([sys.executable, bin_dir / "magfit_before", "--version"], tmp_path, env)
    assert before.returncode == 7 and "pymavlink magfit.py ran" in before.stdout
    # The entry point it has now.
    (bin_dir / "magfit").write_text(CONSOLE_SCRIPT.format(module="_magfit_entry"), encoding="utf-8")
    after = _run([sys.executable, bin_dir / "magfit", "--version"], tmp_path, env)
    assert after.returncode == 0, after.stderr
    assert after.stdout.strip() == f"magfit, version {magfit.__version__}"
    assert "pymavlink" not in after.stdout + after.stderr


def test_only_a_folder_whose_magfit_is_a_plain_module_is_taken_off_the_path(tmp_path: Path) -> None:
    import _magfit_entry

    script_only, with_package, neither = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for folder in (script_only, with_package / "magfit", neither):
        folder.mkdir(parents=True)
    (script_only / "magfit.py").write_text(SHADOW, encoding="utf-8")
    (with_package / "magfit.py").write_text(SHADOW, encoding="utf-8")
    (with_package / "magfit" / "__init__.py").write_text("", encoding="utf-8")  # the package wins there
    assert [_magfit_entry._shadows(str(f)) for f in (script_only, with_package, neither)] == [True, False, False]


def test_python_dash_m_magfit_runs_the_command_line(tmp_path: Path) -> None:
    env = {**_clean_environment(), "PYTHONPATH": str(SRC)}
    result = _run([sys.executable, "-m", "magfit", "--version"], tmp_path, env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"magfit, version {magfit.__version__}"


def _venv_bin(venv: Path) -> Path:
    return venv / ("Scripts" if os.name == "nt" else "bin")


def _pip(venv: Path, arguments: list[str | Path], cwd: Path, env: dict[str, str]) -> None:
    """pip install into ``venv``; a failure (PyPI out of reach) skips, except under CI where it fails."""
    result = _run([_venv_bin(venv) / "python", "-m", "pip", "install", "--quiet", *arguments], cwd, env, timeout=900)
    if result.returncode != 0:
        tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-5:])
        if os.environ.get("CI") == "true":
            pytest.fail(f"pip install {' '.join(map(str, arguments))} failed under CI:\n{tail}")
        pytest.skip(f"pip install {' '.join(map(str, arguments))} failed (PyPI out of reach?):\n{tail}")


@pytest.mark.external
@pytest.mark.slow
def test_magfit_works_with_pymavlink_installed_beside_it(tmp_path: Path) -> None:
    # A throwaway environment: pymavlink (with its dependencies) from PyPI, magfit from this checkout.
    # magfit's own dependencies (numpy, scipy, click, rich) are taken from the running interpreter through
    # a .pth file, so that only pymavlink is downloaded.
    venv = tmp_path / "venv"
    env = _clean_environment()
    created = _run([sys.executable, "-m", "venv", venv], tmp_path, env)
    assert created.returncode == 0, created.stderr
    where = "import sysconfig; print(sysconfig.get_path('purelib'))"
    site_packages = Path(_run([_venv_bin(venv) / "python", "-c", where], tmp_path, env).stdout.strip())
    ours = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib")}
    (site_packages / "zz_test_dependencies.pth").write_text("\n".join(sorted(ours)) + "\n", encoding="utf-8")
    _pip(venv, ["pymavlink"], tmp_path, env)
    bin_dir = _venv_bin(venv)
    assert (bin_dir / "magfit.py").is_file(), "pymavlink no longer puts magfit.py in bin/: this test shows nothing"
    # A copy of the checkout's package (the build leaves nothing in the checkout).
    tree = tmp_path / "tree"
    tree.mkdir()
    for name in ("pyproject.toml", "README.md"):
        (tree / name).write_bytes((ROOT / name).read_bytes())
    shutil.copytree(SRC, tree / "src", ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info"))
    # --ignore-installed: pip sees the running interpreter's packages too, and must never touch them.
    _pip(venv, ["--no-deps", "--ignore-installed", tree], tmp_path, env)

    found = _run([bin_dir / "python", "-c", "import magfit; print(magfit.__file__)"], tmp_path, env)
    assert Path(found.stdout.strip()).is_relative_to(venv), found  # the copy just installed, not the checkout
    # The version is written once (magfit.__version__); the package metadata built from it says the same.
    query = "import importlib.metadata as m; d = m.distribution('magfit'); print(d.version); print(d.locate_file(''))"
    metadata = _run([bin_dir / "python", "-c", query], tmp_path, env).stdout.split("\n")
    assert metadata[0] == magfit.__version__ and Path(metadata[1]).is_relative_to(venv), metadata
    version = _run([bin_dir / "magfit", "--version"], tmp_path, env)
    assert version.returncode == 0, version.stdout + version.stderr
    assert version.stdout.strip() == f"magfit, version {magfit.__version__}"
    module = _run([bin_dir / "python", "-m", "magfit", "--version"], tmp_path, env)
    assert module.returncode == 0 and module.stdout.strip() == version.stdout.strip(), module.stderr
    demo = _run([bin_dir / "magfit", "demo", "--seed", "1"], tmp_path, env, timeout=300)
    assert demo.returncode == 0, demo.stdout + demo.stderr
    assert "ellipsoid" in demo.stdout and "[holds]" in demo.stdout
    # pymavlink's own script still runs as itself (its usage message, not magfit's).
    theirs = _run([bin_dir / "python", bin_dir / "magfit.py", "--help"], tmp_path, env)
    assert "LOG" in theirs.stdout and "calibrate" not in theirs.stdout
