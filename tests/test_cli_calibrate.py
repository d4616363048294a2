"""``magfit calibrate``: ground-truth fits from files, streaming in bounded chunks, JSON and firmware outputs."""

from __future__ import annotations

import io
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
import magfit.io
from magfit.cli import cli
from magfit.cli.calibrate import progress_bar
from magfit.export import FORMATS, export
from magfit.pipeline import streaming as streaming_module


@pytest.fixture(scope="module")
def steel(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, magfit.Simulation]:
    """The paper's Ellipse 2A with the piece of steel, in a CSV with a time column before the magnetometer."""
    simulation = magfit.scenario("ellipse2a", "steel").simulate(3000, seed=31)
    path = tmp_path_factory.mktemp("calibrate") / "steel.csv"
    time = np.arange(3000) * 0.02
    np.savetxt(
        path, np.column_stack([time, simulation.samples]), fmt="%.17g", delimiter=",", header="t,mx,my,mz", comments=""
    )
    return path, simulation


def _assert_close_to_truth(calibration: magfit.Calibration, truth: magfit.Calibration) -> None:
    # Noise is 1.1 % of the field over 3000 samples: the identifiable ellipsoid A comes out within a few
    # tenths of a percent; 2 % of its largest entry still catches any axis or sign mix-up.
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix, truth.ellipsoid_matrix, atol=0.02 * scale)
    np.testing.assert_allclose(calibration.offset, truth.offset, atol=0.01 * truth.field_strength)


def test_calibrate_writes_the_json_and_prints_the_summary(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path
) -> None:
    path, simulation = steel
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(
        cli, ["calibrate", str(path), "--method", "ellipsoid", "-o", str(output), "--unit", "G"]
    )
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.method == "ellipsoid" and calibration.unit == "G" and calibration.n_samples == 3000
    _assert_close_to_truth(calibration, simulation.truth)
    text = result.stdout
    assert re.search(r"columns +mx, my, mz", text)
    assert re.search(r"rows +3000 read, 0 skipped", text)
    for label in ("offset", "matrix", "field strength", "semi-axes", "sphere distance", "convention"):
        assert label in text
    evaluation = magfit.evaluate(calibration, simulation.samples)
    assert f"mean {evaluation.mean:.4f}  std {evaluation.std:.4f}" in text
    assert f"wrote the calibration to {output}" in text
    assert result.stderr == ""  # no warning: nothing was skipped


def test_default_method_is_auto_when_registered(steel: tuple[Path, magfit.Simulation], tmp_path: Path) -> None:
    path, simulation = steel
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    _assert_close_to_truth(calibration, simulation.truth)
    expected = "auto" if "auto" in magfit.METHODS else "ellipsoid"
    assert re.search(rf"method +{calibration.method}", result.stdout)
    if expected == "ellipsoid":
        assert calibration.method == "ellipsoid"


def test_statistics_methods_stream_the_file_in_bounded_chunks(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path, simulation = steel
    original = magfit.io.iter_sample_chunks
    sizes: list[int] = []

    class Recorder:
        """The reader with 500-row chunks, recording each chunk's size; its counters pass through."""

        def __init__(self, *args: object, **kwargs: object) -> None:
            self.reader = original(*args, **{**kwargs, "chunk_rows": 500})  # type: ignore[arg-type]

        def __iter__(self):  # type: ignore[no-untyped-def]
            for chunk in self.reader:
                sizes.append(len(chunk))
                yield chunk

        def parallel_pieces(self) -> list[object]:
            return [self]  # a small file is one piece

        def __getattr__(self, name: str) -> object:
            return getattr(self.reader, name)

    def no_whole_file(*args: object, **kwargs: object) -> None:
        raise AssertionError("a streaming method must not load the whole file")

    monkeypatch.setattr(magfit.io, "iter_sample_chunks", Recorder)
    monkeypatch.setattr(magfit.io, "read_samples", no_whole_file)
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(output)])
    assert result.exit_code == 0, result.output
    # The text is parsed once, never more than 500 rows at a time (the paper's metric, a second pass, reads
    # the samples back from a temporary binary spill).
    assert sum(sizes) == 3000 and max(sizes) <= 500
    streamed = magfit.Calibration.from_json(output.read_text())
    in_memory = magfit.fit(simulation.samples, method="ellipsoid")
    np.testing.assert_allclose(streamed.ellipsoid_matrix, in_memory.ellipsoid_matrix, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(streamed.offset, in_memory.offset, rtol=1e-9, atol=1e-12)
    assert "(streamed)" in result.stdout


@pytest.mark.slow
def test_samples_methods_read_the_whole_file(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    needs_samples = [name for name, spec in magfit.METHODS.items() if spec.data == "samples"]
    if not needs_samples:
        pytest.skip("no registered method needs the samples")
    path, simulation = steel

    def no_streaming(*args: object, **kwargs: object) -> None:
        raise AssertionError("a method that needs the samples must read them with read_samples")

    monkeypatch.setattr(magfit.io, "iter_sample_chunks", no_streaming)
    output = tmp_path / "cal.json"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "-m", needs_samples[0], "-o", str(output)])
    assert result.exit_code == 0, result.output
    _assert_close_to_truth(magfit.Calibration.from_json(output.read_text()), simulation.truth)
    assert "(streamed)" not in result.stdout


def test_export_without_output_goes_to_stdout_and_the_summary_to_stderr(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path
) -> None:
    path, _ = steel
    runner = CliRunner()
    saved = tmp_path / "cal.json"
    assert runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(saved)]).exit_code == 0
    calibration = magfit.Calibration.from_json(saved.read_text())
    result = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "--export", "c"])
    assert result.exit_code == 0, result.output
    assert result.stdout == export(calibration, "c")
    assert "field strength" in result.stderr


def test_export_with_output_writes_the_format_to_that_path(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path
) -> None:
    path, _ = steel
    runner = CliRunner()
    saved = tmp_path / "cal.json"
    assert (
        runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(saved), "--unit", "G"]).exit_code == 0
    )
    calibration = magfit.Calibration.from_json(saved.read_text())
    target = tmp_path / f"mag{FORMATS['ardupilot'].extension}"
    result = runner.invoke(
        cli, ["calibrate", str(path), "-m", "ellipsoid", "--export", "ardupilot", "--unit", "G", "-o", str(target)]
    )
    assert result.exit_code == 0, result.output
    assert target.read_text() == export(calibration, "ardupilot", unit="G")
    assert f"wrote the ardupilot export to {target}" in result.stdout


def test_export_needs_a_known_format_and_unit(steel: tuple[Path, magfit.Simulation], tmp_path: Path) -> None:
    path, _ = steel
    target = tmp_path / "mag.param"
    runner = CliRunner()
    unknown = runner.invoke(cli, ["calibrate", str(path), "--export", "mavlink", "-o", str(target)])
    assert unknown.exit_code == 2
    assert "unknown format 'mavlink'; valid formats: " + ", ".join(FORMATS) in unknown.stderr
    # ArduPilot wants milligauss: without a unit magfit cannot convert, and says so; nothing is written.
    no_unit = runner.invoke(
        cli, ["calibrate", str(path), "-m", "ellipsoid", "--export", "ardupilot", "-o", str(target)]
    )
    assert no_unit.exit_code == 2
    assert no_unit.stderr.startswith("magfit: error: ") and "--unit" in no_unit.stderr
    assert not target.exists()


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_is_shown_only_on_a_terminal(
    steel: tuple[Path, magfit.Simulation], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, simulation = steel
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    run = magfit.calibrate_file(path, "ellipsoid", progress=progress_bar).compasses[0]
    shown = terminal.getvalue()
    assert f"reading {path.name}" in shown and f"scoring the fit on {path.name}" in shown
    assert "100%" in shown and "3,000 rows" in shown  # a bar with the share done: the total is known
    terminal.truncate(0)
    # ml: the whole file is loaded, and the read shows progress too
    in_memory = magfit.calibrate_file(path, "ml", progress=progress_bar).compasses[0]
    assert not in_memory.streamed and f"reading {path.name}" in terminal.getvalue()
    assert run.evaluation.n == 3000 and run.streamed
    piped = io.StringIO()
    monkeypatch.setattr(sys, "stderr", piped)
    again = magfit.calibrate_file(path, "ellipsoid", progress=progress_bar).compasses[0]
    assert piped.getvalue() == ""
    assert again.evaluation == run.evaluation
    whole = magfit.evaluate(run.calibration, simulation.samples)
    assert (run.evaluation.mean, run.evaluation.std) == pytest.approx((whole.mean, whole.std), rel=1e-12)


def test_diagnostic_warnings_and_autos_choice_are_shown(tmp_path: Path) -> None:
    # Roll and pitch within ±40°: about half of the directions are never seen.
    simulation = magfit.scenario("mpu9250", "none").simulate(2000, seed=1, orientations="restricted", max_tilt_deg=40)
    path = tmp_path / "restricted.csv"
    np.savetxt(path, simulation.samples, fmt="%.10g", delimiter=",", header="mx,my,mz", comments="")
    method = "auto" if "auto" in magfit.METHODS else "ellipsoid"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--method", method])
    assert result.exit_code == 0, result.output
    calibration = magfit.fit(simulation.samples, method=method)
    warnings = calibration.details.get("diagnostics", {}).get("warnings", [])
    assert any("cover only" in message for message in warnings)  # the diagnostics saw the gap
    for message in warnings:
        assert f"magfit: warning: {message}" in result.stderr
    if calibration.auto is not None:
        choice = calibration.auto
        chose = rf"chose +{choice.chosen} model, maximum-likelihood fit started from {choice.method_used} \("
        assert re.search(chose, result.stdout)


def test_streamed_fits_are_diagnosed_on_a_bounded_subsample(
    steel: tuple[Path, magfit.Simulation], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path, simulation = steel
    output = tmp_path / "cal.json"
    assert CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(output)]).exit_code == 0
    diagnostics = magfit.Calibration.from_json(output.read_text()).diagnostics
    assert diagnostics is not None and diagnostics.coverage is not None  # not the Statistics-only report
    # Under the cap every row is used: the same report as the in-memory fit's.
    in_memory = magfit.fit(simulation.samples, method="ellipsoid").diagnostics
    assert in_memory is not None and diagnostics.to_dict() == in_memory.to_dict()
    # Over the cap, every k-th row: 3000 rows with a cap of 1000 keep rows 0, 3, 6 ...
    monkeypatch.setattr(streaming_module, "DIAGNOSE_SAMPLES", 1000)
    assert CliRunner().invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(output)]).exit_code == 0
    capped = magfit.Calibration.from_json(output.read_text()).diagnostics
    assert capped is not None and capped.n_samples == 1000
    assert "Streamed: diagnosed on one row in 3 (1000 of 3000)" in capped.notes[-1]
    reference = magfit.diagnose(magfit.Calibration.from_json(output.read_text()), simulation.samples[::3])
    assert capped.coverage == reference.coverage


@pytest.mark.slow
def test_no_method_imports_scipy_optimize(steel: tuple[Path, magfit.Simulation]) -> None:
    # Importing scipy.optimize costs 0.4-0.6 s of CPU: a fifth of a 10-million-row calibrate
    # (benchmarks/speed.py), a third of auto on a million rows. magfit._optimize has the solvers instead.
    import subprocess

    path, _ = steel
    code = (
        "import sys; from pathlib import Path; import magfit\n"
        "ran = []\n"
        "for method in sorted(magfit.METHODS):\n"
        # forced: sphere and minmax are refused on the steel case's soft iron, and every method must run here,
        # but those that need more than the samples (vector: a reference field; gyro: the body rates)
        "    try:\n"
        "        run = magfit.calibrate_file(Path(sys.argv[1]), method, force=True)\n"
        "    except magfit.OptionError as error:\n"
        "        assert ' needs ' in str(error), error\n"
        "        continue\n"
        "    assert run.calibration.diagnostics is not None\n"
        "    ran.append(method)\n"
        "assert {'als', 'auto', 'diag', 'ellipsoid', 'minmax', 'ml', 'robust', 'sphere'} <= set(ran), ran\n"
        "print(sorted(m for m in sys.modules if 'scipy' in m))"
    )
    result = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert "'scipy.optimize'" not in result.stdout, result.stdout


def test_system_id_goes_into_the_px4_file_and_nowhere_else(tmp_path: Path) -> None:
    sim = magfit.simulate(2000, field_strength=50.0, hard_iron=[10.0, -20.0, 30.0], noise=0.5, seed=4)
    path = tmp_path / "mag.csv"
    np.savetxt(path, sim.samples, delimiter=",", header="mx,my,mz", comments="")
    runner = CliRunner()
    result = runner.invoke(cli, ["calibrate", str(path), "--unit", "uT", "--export", "px4", "--system-id", "3"])
    assert result.exit_code == 0, result.output
    rows = [line.split("\t") for line in result.stdout.splitlines() if line and not line.startswith("#")]
    assert rows and all(row[0] == "3" for row in rows)
    refused = runner.invoke(cli, ["calibrate", str(path), "--system-id", "3", "-o", str(tmp_path / "cal.json")])
    assert refused.exit_code == 2 and "--system-id goes with --export px4" in refused.output
    assert not (tmp_path / "cal.json").exists()


@pytest.mark.slow
def test_a_self_judged_method_prints_its_weaknesses_as_warnings() -> None:
    # gyro judges itself (calibration.support, no report of its own): its diagnostics carry that verdict, and the
    # summary's "weak: n weakness(es), in the warnings above" must have those warnings above it.
    from magfit.cli.calibrate import _fit_warnings, _verdict
    from magfit.vehicle import simulate_vehicle

    sim = simulate_vehicle(3000, "boat", rate_hz=10.0, noise=0.005, gyro_noise=0.002, seed=3)
    calibration = magfit.fit(sim.samples, method="gyro", gyro=sim.gyro, time_s=sim.time_s)
    weaknesses = list(calibration.support.weaknesses)
    assert calibration.support.verdict == "weak" and weaknesses
    assert calibration.diagnostics is not None and calibration.diagnostics.support.verdict == "weak"
    assert _fit_warnings(calibration) == weaknesses
    assert _verdict(calibration) == [("verdict", f"weak: {len(weaknesses)} weakness(es), in the warnings above")]
