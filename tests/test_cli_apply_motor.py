"""``magfit apply`` with a calibration that holds the motors' field: the regressor from the log or a column.

The calibration is the simulated flight's truth (magfit.motorsim), so every corrected file is compared with the
true field in the body frame: the tilt-compensated heading against the true attitude.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from magfit import Calibration
from magfit.cli import cli
from magfit.motorsim import MotorFlight, heading_error_deg, simulate_motor_flight
from test_motor_logs import write_flight


@pytest.fixture(scope="module")
def flight() -> MotorFlight:
    return simulate_motor_flight(60, driver="current", per_unit=4.0, seed=5)


@pytest.fixture
def files(tmp_path: Path, flight: MotorFlight) -> tuple[Path, Path]:
    """The truth as a calibration file, and a CSV of the flight: time, the raw field, the logged current."""
    cal = tmp_path / "truth.json"
    cal.write_text(flight.truth.to_json())
    csv = tmp_path / "quad.csv"
    table = np.column_stack([flight.time_s, flight.samples, flight.current])
    np.savetxt(csv, table, fmt="%.10g", delimiter=",", header="time_s,mx,my,mz,bat_curr", comments="")
    return cal, csv


def _heading(path: Path, flight: MotorFlight) -> float:
    written = np.loadtxt(path, delimiter=",", skiprows=1)
    return heading_error_deg(written[:, 1:4], flight.attitude, flight.field_ned)


def test_the_current_column_found_by_name_gives_the_truths_heading(
    files: tuple[Path, Path], flight: MotorFlight, tmp_path: Path
) -> None:
    cal, csv = files
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(csv), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "'bat_curr'" in result.stdout and "found by name" in result.stdout
    lagged = np.interp(flight.time_s - flight.lag_s, flight.time_s, flight.current)
    expected = flight.truth.apply(flight.samples, regressor=lagged)
    written = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(written[:, 1:4], expected, rtol=1e-8, atol=1e-6)
    np.testing.assert_array_equal(written[:, 4], np.loadtxt(csv, delimiter=",", skiprows=1)[:, 4])
    assert _heading(out, flight) < 1.0


def test_leaving_the_term_out_is_said_with_its_cost(
    files: tuple[Path, Path], flight: MotorFlight, tmp_path: Path
) -> None:
    cal, csv = files
    out = tmp_path / "plain.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(csv), "--no-motor", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "--no-motor" in result.stderr and "deg of heading error" in result.stderr
    with_term = tmp_path / "term.csv"
    assert CliRunner().invoke(cli, ["apply", str(cal), str(csv), "-o", str(with_term)]).exit_code == 0
    assert _heading(out, flight) > 3 * _heading(with_term, flight)


def test_a_column_named_or_numbered_by_regressor(files: tuple[Path, Path], flight: MotorFlight, tmp_path: Path) -> None:
    cal, csv = files
    renamed = tmp_path / "renamed.csv"
    renamed.write_text(csv.read_text().replace("bat_curr", "amps_pm", 1))
    for given in ("amps_pm", "4"):
        out = tmp_path / f"out_{given}.csv"
        result = CliRunner().invoke(cli, ["apply", str(cal), str(renamed), "--regressor", given, "-o", str(out)])
        assert result.exit_code == 0, result.output
        assert _heading(out, flight) < 1.0


def test_without_the_regressor_one_line_exit_2_naming_what_is_missing(files: tuple[Path, Path], tmp_path: Path) -> None:
    cal, csv = files
    renamed = tmp_path / "renamed.csv"
    renamed.write_text(csv.read_text().replace("bat_curr", "other", 1))
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(renamed), "-o", str(out)])
    assert result.exit_code == 2
    message = result.stderr.strip()
    assert len(message.splitlines()) == 1
    assert "--regressor" in message and "--no-motor" in message and "deg of heading" in message
    assert not out.exists()


def test_regressor_given_to_a_calibration_without_the_term_is_refused(
    files: tuple[Path, Path], flight: MotorFlight, tmp_path: Path
) -> None:
    _, csv = files
    cal = tmp_path / "plain.json"
    cal.write_text(Calibration.identity().to_json())
    result = CliRunner().invoke(
        cli, ["apply", str(cal), str(csv), "--regressor", "bat_curr", "-o", str(tmp_path / "o.csv")]
    )
    assert result.exit_code == 2
    assert "--regressor" in result.stderr and "no motors' field" in result.stderr


def test_a_throttle_column_in_percent_is_refused(tmp_path: Path) -> None:
    flight = simulate_motor_flight(30, driver="throttle", per_unit=150.0, seed=2)
    cal = tmp_path / "truth.json"
    cal.write_text(flight.truth.to_json())
    csv = tmp_path / "t.csv"
    table = np.column_stack([flight.time_s, flight.samples, 100 * flight.throttle])
    np.savetxt(csv, table, fmt="%.10g", delimiter=",", header="time_s,mx,my,mz,throttle", comments="")
    result = CliRunner().invoke(cli, ["apply", str(cal), str(csv), "-o", str(tmp_path / "o.csv")])
    assert result.exit_code == 2
    assert "divide a percentage by 100" in result.stderr
    np.savetxt(csv, np.column_stack([flight.time_s, flight.samples, flight.throttle]), fmt="%.10g", delimiter=",",
               header="time_s,mx,my,mz,throttle", comments="")  # fmt: skip
    assert CliRunner().invoke(cli, ["apply", str(cal), str(csv), "-o", str(tmp_path / "o.csv")]).exit_code == 0
    assert _heading(tmp_path / "o.csv", flight) < 1.0


def test_an_npy_file_with_a_current_column(flight: MotorFlight, tmp_path: Path) -> None:
    cal = tmp_path / "truth.json"
    cal.write_text(flight.truth.to_json())
    path = tmp_path / "quad.npy"
    np.save(path, np.column_stack([flight.samples, flight.current]))
    out = tmp_path / "out.npy"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(path), "--columns", "0,1,2", "--regressor", "3",
                                      "-o", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "no time column" in result.stdout  # the lag cannot be applied without stamps: said
    written = np.load(out)
    np.testing.assert_allclose(written[:, :3], flight.truth.apply(flight.samples, regressor=flight.current))


def test_a_log_is_corrected_with_its_own_current(flight: MotorFlight, tmp_path: Path) -> None:
    cal = tmp_path / "truth.json"
    cal.write_text(flight.truth.to_json())
    log = write_flight(tmp_path / "quad.bin", flight)
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(log), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "BAT.Curr" in result.stdout
    assert _heading(out, flight) < 1.0
    plain = tmp_path / "plain.csv"
    assert CliRunner().invoke(cli, ["apply", str(cal), str(log), "--no-motor", "-o", str(plain)]).exit_code == 0
    assert _heading(plain, flight) > 3 * _heading(out, flight)
    given = CliRunner().invoke(cli, ["apply", str(cal), str(log), "--regressor", "x", "-o", str(tmp_path / "o.csv")])
    assert given.exit_code == 2 and "is a log" in given.stderr


def test_a_log_without_the_current_is_refused_in_one_line(flight: MotorFlight, tmp_path: Path) -> None:
    cal = tmp_path / "truth.json"
    cal.write_text(flight.truth.to_json())
    log = write_flight(tmp_path / "quad.bin", flight, bat=False)
    result = CliRunner().invoke(cli, ["apply", str(cal), str(log), "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 2
    errors = [line for line in result.stderr.splitlines() if line.startswith("magfit: error:")]
    assert len(errors) == 1 and errors[0] == result.stderr.strip().splitlines()[-1]
    assert "BAT.Curr" in errors[0] and "--no-motor" in errors[0] and "deg of heading" in errors[0]


def test_a_ulog_is_corrected_with_its_battery_current(flight: MotorFlight, tmp_path: Path) -> None:
    pytest.importorskip("pyulog")
    from magfit.motorterm import MotorTerm
    from test_motor_logs import write_px4_flight

    truth, term = flight.truth, flight.truth.motor
    assert term is not None
    in_gauss = Calibration(
        "truth", truth.offset * 1e-3, truth.matrix, truth.field_strength * 1e-3, unit="G",
        motor=MotorTerm("current", term.coefficients * 1e-3, lag_s=term.lag_s, full_scale=term.full_scale),
    )  # fmt: skip
    cal = tmp_path / "truth_g.json"
    cal.write_text(in_gauss.to_json())
    log = write_px4_flight(tmp_path / "quad.ulg", flight)
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["apply", str(cal), str(log), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "battery_status.current_a" in result.stdout
    assert _heading(out, flight) < 1.0
