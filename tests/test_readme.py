"""The README's promises: its commands and its library example stay true."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def code_blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)


def test_readme_starts_with_the_two_commands() -> None:
    first_two = code_blocks("sh")[:2]
    assert "magfit demo" in first_two[0] and "pip install" in first_two[0]
    assert "pytest" in first_two[1] and ".[test]" in first_two[1]


def test_readme_library_example_runs(capsys) -> None:  # type: ignore[no-untyped-def]
    (example,) = [block for block in code_blocks("python") if "import magfit" in block][:1]
    exec(compile(example, str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "ellipsoid mean" in printed and "minmax" in printed


def _golden_script():  # type: ignore[no-untyped-def]
    import importlib.util
    import sys

    path = README.parent / "scripts" / "regenerate_golden.py"
    spec = importlib.util.spec_from_file_location("regenerate_golden", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)
    return module


GOLDEN = _golden_script()


@pytest.mark.parametrize("example", GOLDEN.README_EXAMPLES, ids=lambda example: example.command)
def test_readme_example_output_is_the_programs(example, real_data_dir: Path) -> None:  # type: ignore[no-untyped-def]
    """The README's `magfit calibrate` block, run on the real recording: its output must be the program's."""
    shown = GOLDEN.readme_block(README.read_text(encoding="utf-8"), example).group(1)
    produced = GOLDEN.run_readme_example(example, real_data_dir)
    assert shown == produced, "the README's example is out of date: run `python scripts/regenerate_golden.py`"


# ---------------------------------------------------------------------- the README's claims, run


def _text() -> str:
    return " ".join(README.read_text(encoding="utf-8").split())


def _write(path: Path, samples) -> Path:  # type: ignore[no-untyped-def]
    import numpy as np

    np.savetxt(path, samples, delimiter=",", header="mx,my,mz", comments="")
    return path


def _yaw_only():  # type: ignore[no-untyped-def]
    import magfit

    return magfit.scenario("mpu9250", "none").simulate(1500, seed=1, orientations="yaw").samples


def test_calibrate_file_returns_a_file_calibration_that_iterates_over_compass_calibrations(tmp_path: Path) -> None:
    import numpy as np

    import magfit
    from magfit.pipeline import CompassCalibration, FileCalibration

    assert "returns a `FileCalibration`; iterating it gives one `CompassCalibration` per compass" in _text()
    sim = magfit.scenario("mpu9250", "steel").simulate(2000, seed=3)
    result = magfit.calibrate_file(_write(tmp_path / "steel.csv", sim.samples), "ellipsoid")
    assert isinstance(result, FileCalibration)
    (compass,) = list(result)
    assert isinstance(compass, CompassCalibration) and compass.calibration is result.calibration
    # Against the truth: the README's promise is about a calibration, not only about types.
    np.testing.assert_allclose(compass.calibration.offset, sim.truth.offset, atol=10.0)  # counts, of 193-1362
    assert result.failures == ()


@pytest.mark.parametrize("method", ["sphere", "auto"])
@pytest.mark.slow
def test_allow_undetermined_returns_it_all_the_same_refusal_first(method: str) -> None:
    import magfit

    assert "`allow_undetermined=True` (`--force`, exit 0) returns it all the same" in _text()
    samples = _yaw_only()
    with pytest.raises(magfit.CalibrationError):
        magfit.fit(samples, method)
    forced = magfit.fit(samples, method, allow_undetermined=True)
    assert forced.support.forced is True
    assert forced.diagnostics is not None and forced.diagnostics.warnings[0].startswith("NOT SUPPORTED (forced): ")


@pytest.mark.parametrize("method", ["sphere", "auto"])
@pytest.mark.slow
def test_force_on_the_command_line_exits_0_and_writes_it_marked(tmp_path: Path, method: str) -> None:
    from click.testing import CliRunner

    import magfit
    from magfit.cli import cli

    path = _write(tmp_path / "yaw.csv", _yaw_only())
    out = tmp_path / "cal.json"
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "-m", method, "-o", str(out)])
    assert refused.exit_code == 1 and not out.exists()
    forced = CliRunner().invoke(cli, ["calibrate", str(path), "-m", method, "--force", "-o", str(out)])
    assert forced.exit_code == 0, forced.output
    assert magfit.Calibration.from_json(out.read_text()).support.forced is True


def test_calibrate_prints_the_verdict_the_coverage_and_the_heading_one_sigma_of_a_supported_fit(
    tmp_path: Path,
) -> None:
    from click.testing import CliRunner

    import magfit
    from magfit.cli import cli

    assert "`magfit calibrate` prints the verdict, the share of directions covered and the heading one-sigma" in _text()
    path = _write(tmp_path / "steel.csv", magfit.scenario("mpu9250", "steel").simulate(3000, seed=4).samples)
    out = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(out)])
    assert result.exit_code == 0, result.output
    lines = {line.split(maxsplit=1)[0]: line for line in result.stdout.splitlines() if line.strip()}
    assert lines["verdict"].split()[1] == "supported"
    saved = magfit.Calibration.from_json(out.read_text()).diagnostics
    assert saved is not None and saved.uncertainty is not None and saved.uncertainty.heading_sigma_deg
    # The numbers printed are the ones saved: one uncertainty.
    assert f"{100 * saved.coverage.share:.0f} %" in lines["coverage"]
    assert f"± {saved.uncertainty.heading_sigma_deg:.2g}° one-sigma" in lines["heading"]
