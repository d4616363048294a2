"""A missing optional extra is one line with the install command, exit status 2, before any file is written."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit.cli import cli
from magfit.cli._common import EXIT_USAGE, as_command_error

HINT = "pip install 'magfit[plot]'"


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(400, 3))
    samples = 48.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True) + (5.0, -3.0, 2.0)
    path = tmp_path / "mag.csv"
    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="")
    return path


@pytest.fixture
def without_matplotlib(monkeypatch: pytest.MonkeyPatch) -> None:
    """As if the plot extra were not installed: importing matplotlib (or any submodule) fails."""
    for name in list(sys.modules):
        if name == "matplotlib" or name.startswith("matplotlib."):
            monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)


def _check_hint(result: object, tmp_path: Path, before: set[Path]) -> None:
    assert result.exit_code == EXIT_USAGE, result.output  # type: ignore[attr-defined]
    lines = result.stderr.strip().splitlines()  # type: ignore[attr-defined]
    assert len(lines) == 1 and lines[0].startswith("magfit: error: ") and HINT in lines[0], lines
    assert "Traceback" not in result.output and "bug" not in result.output  # type: ignore[attr-defined]
    assert set(tmp_path.iterdir()) == before, "a file was written before the missing extra was noticed"


@pytest.mark.usefixtures("without_matplotlib")
def test_plot_without_the_plot_extra(recording: Path, tmp_path: Path) -> None:
    before = set(tmp_path.iterdir())
    result = CliRunner().invoke(cli, ["plot", str(recording), "-o", str(tmp_path / "mag.png")])
    _check_hint(result, tmp_path, before)


@pytest.mark.usefixtures("without_matplotlib")
def test_calibrate_plot_writes_nothing_without_the_plot_extra(recording: Path, tmp_path: Path) -> None:
    before = set(tmp_path.iterdir())
    result = CliRunner().invoke(
        cli, ["calibrate", str(recording), "-o", str(tmp_path / "cal.json"), "--plot", str(tmp_path / "mag.png")]
    )
    _check_hint(result, tmp_path, before)


@pytest.mark.usefixtures("without_matplotlib")
def test_report_without_the_plot_extra(recording: Path, tmp_path: Path) -> None:
    before = set(tmp_path.iterdir())
    result = CliRunner().invoke(cli, ["report", str(recording), "-o", str(tmp_path / "report.html")])
    _check_hint(result, tmp_path, before)


@pytest.mark.usefixtures("without_matplotlib")
def test_demo_report_without_the_plot_extra(tmp_path: Path) -> None:
    before = set(tmp_path.iterdir())
    result = CliRunner().invoke(cli, ["demo", "-n", "100", "--report", str(tmp_path / "demo.html")])
    _check_hint(result, tmp_path, before)
    assert result.stdout == ""  # stopped before the experiment ran, not after printing its tables


def test_calibrate_without_plot_does_not_need_the_plot_extra(
    recording: Path, tmp_path: Path, without_matplotlib: None
) -> None:
    result = CliRunner().invoke(cli, ["calibrate", str(recording), "-o", str(tmp_path / "cal.json")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "cal.json").exists()


def test_an_import_error_of_an_extra_reaching_the_boundary_is_a_hint_not_a_bug() -> None:
    error = as_command_error(ModuleNotFoundError("No module named 'plotly'", name="plotly"))
    assert error.exit_code == EXIT_USAGE
    assert error.format_message() == "plotly is not installed (the plot extra for the HTML report): " + HINT
    other = as_command_error(ModuleNotFoundError("No module named 'nothing_like_it'", name="nothing_like_it"))
    assert other.exit_code == 3  # an import that is no extra's stays a bug report


def test_the_cli_extra_installs_the_plot_extra() -> None:
    """The README's first command installs `.[cli]`: every command, pictures included, must then work."""
    text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text(encoding="utf-8")
    (cli_extra,) = [line for line in text.splitlines() if line.startswith("cli = [")]
    assert '"magfit[plot]"' in cli_extra


@pytest.mark.usefixtures("without_matplotlib")
def test_the_library_says_how_to_install_matplotlib() -> None:
    import magfit
    from magfit.plot import calibration_figure

    samples = magfit.scenario("mpu9250", "none").simulate(300, seed=1).samples
    with pytest.raises(ImportError, match=r"^drawing figures needs matplotlib \(.*\): pip install 'magfit\[plot\]'$"):
        calibration_figure(samples, magfit.fit(samples, method="sphere"))
