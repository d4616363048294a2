"""Bad input through the command line: exit status, a one-line message that names the problem, no output file.

Exit statuses: 1 when a fit fails on the data, 2 on a usage or input error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

import magfit
from magfit.cli import cli
from magfit.remedy import for_command_line, option


def _run(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args))


def _assert_error(result: Result, status: int, *fragments: str) -> str:
    """The run failed with ``status`` and one line ``magfit: error: ...`` holding every fragment."""
    assert result.exit_code == status, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), "a traceback escaped"
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("magfit: error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def _good_samples(n: int = 400, seed: int = 1) -> np.ndarray:
    return magfit.scenario("mpu9250", "none").simulate(n, seed=seed).samples


def _csv(path: Path, samples: np.ndarray, header: str = "mx,my,mz") -> Path:
    np.savetxt(path, samples, fmt="%.10g", delimiter=",", header=header, comments="")
    return path


# ---------------------------------------------------------------------- unreadable files: exit 2


def test_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.csv"
    for command in ("calibrate", "compare"):
        _assert_error(_run(command, str(missing)), 2, str(missing))


def test_empty_file(tmp_path: Path) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    message = _assert_error(_run("calibrate", str(empty)), 2, str(empty))
    assert "empty" in message


def test_header_without_rows(tmp_path: Path) -> None:
    path = tmp_path / "header.csv"
    path.write_text("mx,my,mz\n")
    message = _assert_error(_run("calibrate", str(path), "-m", "ellipsoid"), 2, str(path))
    assert "no data" in message or "no rows" in message or "empty" in message


def test_non_numeric_cell_names_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    lines = ["mx,my,mz"] + [f"{x:.3f},{y:.3f},{z:.3f}" for x, y, z in _good_samples(20)]
    lines[5] = "1.0,abc,3.0"  # line 6 of the file, column my
    path.write_text("\n".join(lines) + "\n")
    for command in ("calibrate", "compare"):
        message = _assert_error(_run(command, str(path)), 2, str(path), "6")
        assert "my" in message or "column 2" in message
        assert "abc" in message


def test_ragged_row_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "ragged.csv"
    lines = ["mx,my,mz"] + [f"{x:.3f},{y:.3f},{z:.3f}" for x, y, z in _good_samples(20)]
    lines[3] = "1.0,2.0"  # line 4
    path.write_text("\n".join(lines) + "\n")
    _assert_error(_run("calibrate", str(path)), 2, str(path), "4")


# ---------------------------------------------------------------------- non-finite rows


@pytest.fixture
def with_nans(tmp_path: Path) -> Path:
    samples = _good_samples(400)
    samples[[10, 200], 1] = np.nan  # lines 12 and 202 of the file (line 1 is the header)
    samples[300, 2] = np.inf
    return _csv(tmp_path / "nan.csv", samples)


def test_nan_rows_are_skipped_with_a_warning(with_nans: Path, tmp_path: Path) -> None:
    output = tmp_path / "cal.json"
    result = _run("calibrate", str(with_nans), "-m", "ellipsoid", "-o", str(output))
    assert result.exit_code == 0, result.output
    assert result.stderr.startswith(f"magfit: warning: {with_nans}: skipped 3 of 400 rows with NaN or inf values")
    assert "12" in result.stderr and "--nonfinite error" in result.stderr
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.n_samples == 397
    compared = _run("compare", str(with_nans))
    assert compared.exit_code == 0 and "skipped 3 of 400 rows" in compared.stderr


def test_nonfinite_error_refuses_the_file(with_nans: Path, tmp_path: Path) -> None:
    output = tmp_path / "cal.json"
    message = _assert_error(
        _run("calibrate", str(with_nans), "--nonfinite", "error", "-o", str(output)), 2, str(with_nans), "12"
    )
    assert "nan" in message.lower()
    assert "--nonfinite skip" in message  # the library's hint, worded as the command line's option
    assert not output.exists()


# ---------------------------------------------------------------------- fits that fail on the data: exit 1


def test_fewer_samples_than_the_method_needs(tmp_path: Path) -> None:
    path = _csv(tmp_path / "few.csv", _good_samples(6))
    output = tmp_path / "cal.json"
    _assert_error(
        _run("calibrate", str(path), "-m", "ellipsoid", "-o", str(output)), 1, "needs at least 9 samples, got 6"
    )
    assert not output.exists()


def test_data_that_do_not_span_three_dimensions(tmp_path: Path) -> None:
    # Level turns only of an undisturbed sensor with the field in the horizontal plane: a flat ring.
    ring = magfit.simulate(500, hard_iron=[3.0, -2.0, 1.0], inclination_deg=0.0, orientations="yaw", seed=3).samples
    path = _csv(tmp_path / "ring.csv", ring)
    _assert_error(_run("calibrate", str(path), "-m", "ellipsoid"), 1, "do not span three dimensions")


def test_a_fit_that_is_not_an_ellipsoid_suggests_a_remedy(tmp_path: Path) -> None:
    # Samples on a one-sheet hyperboloid x² + y² − z² = 1: three-dimensional, but no ellipsoid.
    rng = np.random.default_rng(5)
    angle, height = rng.uniform(0, 2 * np.pi, 600), rng.uniform(-1.0, 1.0, 600)
    radius = np.sqrt(1 + height**2)
    path = _csv(tmp_path / "hyperboloid.csv", np.column_stack([radius * np.cos(angle), radius * np.sin(angle), height]))
    output = tmp_path / "cal.json"
    output.write_text("previous calibration\n")
    message = _assert_error(_run("calibrate", str(path), "-m", "ellipsoid", "-o", str(output)), 1, "ellipsoid")
    assert "sphere" in message or "attitudes" in message or "rotat" in message
    assert output.read_text() == "previous calibration\n"  # a failed run does not clobber the output


# ---------------------------------------------------------------------- usage errors: exit 2


def test_output_path_that_is_the_input_is_refused(tmp_path: Path) -> None:
    path = _csv(tmp_path / "data.csv", _good_samples())
    before = path.read_bytes()
    _assert_error(_run("calibrate", str(path), "-o", str(path)), 2, f"the output {path} is the input file")
    assert path.read_bytes() == before


def test_unknown_method_lists_the_valid_ones(tmp_path: Path) -> None:
    path = _csv(tmp_path / "data.csv", _good_samples())
    message = _assert_error(_run("calibrate", str(path), "--method", "magic"), 2, "unknown method 'magic'")
    assert "valid methods: " + ", ".join(magfit.METHODS) in message


def test_unknown_export_format_lists_the_valid_ones(tmp_path: Path) -> None:
    path = _csv(tmp_path / "data.csv", _good_samples())
    message = _assert_error(_run("calibrate", str(path), "--export", "mavlink"), 2, "unknown format 'mavlink'")
    assert "json" in message and "ardupilot" in message


def test_bad_columns_option(tmp_path: Path) -> None:
    path = _csv(tmp_path / "data.csv", _good_samples())
    _assert_error(_run("calibrate", str(path), "--columns", "mx,my"), 2, "three comma-separated column names")
    message = _assert_error(_run("calibrate", str(path), "--columns", "a,b,c"), 2, str(path))
    assert "a" in message


def test_debug_shows_the_traceback(tmp_path: Path) -> None:
    path = _csv(tmp_path / "few.csv", _good_samples(6))
    result = CliRunner().invoke(cli, ["--debug", "calibrate", str(path), "-m", "ellipsoid"])
    assert result.exit_code == 1
    assert isinstance(result.exception, magfit.CalibrationError)


def test_a_file_of_only_nan_rows_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "allnan.csv"
    path.write_text("mx,my,mz\nnan,1,2\n3,nan,4\n")
    message = _assert_error(_run("calibrate", str(path)), 2, str(path), "line 2")
    assert "--columns X,Y,Z" in message  # the reader's hint, worded as the option


@pytest.mark.parametrize(
    ("name", "value", "command_line"),
    [
        ("nonfinite", "skip", "--nonfinite skip"),
        ("unit", "uT", "--unit uT"),
        ("method", "sphere", "--method sphere"),
        ("columns", "...", "--columns X,Y,Z"),
        ("columns", ["mx", "my", "mz"], "--columns mx,my,mz"),
        ("allow_undetermined", True, "--force"),
    ],
)
def test_library_hints_are_worded_as_options(name: str, value: object, command_line: str) -> None:
    with for_command_line():
        assert option(name, value) == command_line
