"""The default fit of a vehicle's recording (magfit.pipeline.vehicle): when the magnitude-only fit (auto) refuses
it, the vector and gyro methods on the streams the recording holds; the best-determined returned, its stated
one-sigma covering its error against the simulated truth; their findings added to the refusal when they refuse
too. An explicit ``--method auto`` is auto alone."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.vehicle import VehicleSimulation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from vehicle_recordings import save_columns, vehicle_recording


def _heading_error(cal: magfit.Calibration, sim: VehicleSimulation) -> float:
    """RMS heading error (degrees) over the recording with the TRUE attitude (a sensor-frame calibration is given
    the true mounting)."""
    body = cal.apply(sim.clean) if cal.frame == "vehicle" else cal.apply(sim.clean) @ sim.mounting.T
    world = np.einsum("kij,kj->ki", sim.attitude, body)
    truth = np.arctan2(sim.field_world[1], sim.field_world[0])
    wrapped = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(wrapped**2)))


def _stated(cal: magfit.Calibration) -> float:
    assert cal.diagnostics is not None and cal.diagnostics.uncertainty is not None
    sigma = cal.diagnostics.uncertainty.heading_sigma_deg
    assert sigma is not None
    return float(sigma)


@pytest.mark.parametrize(("motion", "seed"), [("car", 0), ("car", 2), ("boat", 1), ("flight", 0)])
def test_the_default_fits_a_vehicle_s_own_streams_within_its_stated_one_sigma(
    tmp_path: Path, motion: str, seed: int
) -> None:
    sim, columns = vehicle_recording(motion, seed)
    path = save_columns(tmp_path / f"{motion}.csv", columns)
    with pytest.raises(magfit.CalibrationError) as alone:  # auto alone cannot: the tilt is too small
        magfit.calibrate_file(path, "auto", unit="uT")
    assert {"undetermined", "model_inadequate"} & set(alone.value.codes)
    result = magfit.calibrate_file(path, unit="uT")
    compass = result.compasses[0]
    cal = compass.calibration
    assert cal.method in ("vector", "gyro")
    assert cal.support is not None and cal.support.verdict in ("supported", "weak")
    assert _heading_error(cal, sim) <= 3 * _stated(cal), (_heading_error(cal, sim), _stated(cal))
    assert cal.method in compass.notes[0] and alone.value.codes[0] in compass.notes[0]  # which method, and why


def test_the_best_determined_of_the_vehicle_methods_is_returned(tmp_path: Path) -> None:
    sim, columns = vehicle_recording("car", 1)
    path = save_columns(tmp_path / "car.csv", columns)
    stated = {}
    for method in ("vector", "gyro"):
        fitted = magfit.calibrate_file(path, method, unit="uT").compasses[0].calibration
        stated[method] = (fitted.support.verdict != "supported", _stated(fitted))
    chosen = magfit.calibrate_file(path, unit="uT").compasses[0].calibration
    assert chosen.method == min(stated, key=lambda method: stated[method])
    assert _heading_error(chosen, sim) <= 3 * _stated(chosen)


def test_the_command_line_default_says_which_method_and_writes_it(tmp_path: Path) -> None:
    sim, columns = vehicle_recording("car", 1)
    path, out = save_columns(tmp_path / "car.csv", columns), tmp_path / "cal.json"
    explicit = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "--method", "auto"])
    assert explicit.exit_code == 1, explicit.output  # --method auto given: auto alone
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "-o", str(out)])
    assert result.exit_code == 0, result.output
    fitted = magfit.Calibration.from_json(out.read_text())
    assert f"calibrated by the {fitted.method} method" in result.stderr
    assert _heading_error(fitted, sim) <= 3 * _stated(fitted)


def test_when_every_method_refuses_the_refusal_says_what_each_found(tmp_path: Path) -> None:
    _, columns = vehicle_recording("yaw", 0)  # level turns only: nothing determines the offset along the vertical
    path = save_columns(tmp_path / "level.csv", columns)
    with pytest.raises(magfit.CalibrationError) as alone:
        magfit.calibrate_file(path, "auto", unit="uT")
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.calibrate_file(path, unit="uT")
    assert set(alone.value.codes) < set(refused.value.codes)  # the vector and gyro fits' codes added
    assert "vector (" in str(refused.value) and "gyro (" in str(refused.value)
    run = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT"])
    assert run.exit_code == 1 and "Traceback" not in run.output
    assert "--method vector" not in run.stderr and "--method gyro" not in run.stderr  # tried: not advised again


def test_a_tumble_is_fitted_by_auto_as_before(tmp_path: Path) -> None:
    sim, columns = vehicle_recording("tumble", 0)
    path = save_columns(tmp_path / "tumble.csv", columns)
    cal = magfit.calibrate_file(path, unit="uT").compasses[0].calibration
    assert cal.method == "auto" and cal.support.verdict == "supported"
    assert _heading_error(cal, sim) <= 3 * _stated(cal)


def test_a_plain_samples_file_is_refused_as_auto_refuses_it(tmp_path: Path) -> None:
    sim, _ = vehicle_recording("car", 1)
    path = tmp_path / "mag.csv"
    np.savetxt(path, sim.samples, fmt="%.6f", delimiter=",", header="mx,my,mz", comments="")
    with pytest.raises(magfit.CalibrationError) as alone:
        magfit.calibrate_file(path, "auto", unit="uT")
    with pytest.raises(magfit.CalibrationError) as default:
        magfit.calibrate_file(path, unit="uT")
    assert str(default.value) == str(alone.value) and default.value.codes == alone.value.codes


def test_force_keeps_auto_s_own_forced_fit(tmp_path: Path) -> None:
    _, columns = vehicle_recording("car", 1)
    path = save_columns(tmp_path / "car.csv", columns)
    cal = magfit.calibrate_file(path, unit="uT", force=True).compasses[0].calibration
    assert cal.method == "auto" and cal.support.verdict == "refused"


@pytest.mark.slow
def test_a_log_s_refused_compass_is_fitted_from_its_own_streams(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A DataFlash log of level turns (roll ±0.06 rad, pitch ±0.03), no GNSS: auto refuses, and the default tries
    the log's IMU (gyro) and attitude (vector, refused: no fix). Its fit is within 3x its stated one-sigma of the
    truth (test_sources_motion's field); a refusal says what each tried found, with their codes."""
    import test_sources_motion as motion_log

    def turns(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.column_stack([0.06 * np.sin(0.31 * t), 0.03 * np.sin(0.23 * t + 1.0), 0.7 * t])
        da = np.column_stack([0.06 * 0.31 * np.cos(0.31 * t), 0.03 * 0.23 * np.cos(0.23 * t + 1.0), 0.7 + 0 * t])
        return a, da

    clean = motion_log.raw_field
    monkeypatch.setattr(motion_log, "euler", turns)
    monkeypatch.setattr(motion_log, "raw_field", lambda t, mounting=None, noise=0.5, seed=0: clean(t, mounting, 3.0))
    formats, rows = motion_log.dataflash_messages(n_mag=2400)
    path = motion_log.write_bin(tmp_path / "turns.bin", formats, rows)
    with pytest.raises(magfit.CalibrationError) as alone:
        magfit.calibrate_file(path, "auto")
    assert "undetermined" in alone.value.codes
    try:
        compass = magfit.calibrate_file(path).compasses[0]
    except magfit.CalibrationError as refused:  # (the gyro fit's own verdict on this log)
        assert set(alone.value.codes) < set(refused.codes) and "gyro (" in str(refused) and "vector (" in str(refused)
        return
    cal = compass.calibration
    assert cal.method == "gyro" and "gyro" in compass.notes[0]  # (vector: no GNSS fix, no location)
    t = 1.0 + np.arange(2400) / 20.0
    world = np.einsum("kij,kj->ki", motion_log.attitude(t), cal.apply(clean(t, None, 0.0)))
    truth = np.arctan2(motion_log.FIELD_NED[1], motion_log.FIELD_NED[0])
    error = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    assert float(np.sqrt(np.mean(error**2))) <= 3 * _stated(cal)


def test_a_log_without_gnss_takes_the_location_given_for_the_vector_method(tmp_path: Path) -> None:
    import test_sources_motion as motion_log

    formats, rows = motion_log.dataflash_messages(n_mag=1200)  # a tumble, no GPS
    path = motion_log.write_bin(tmp_path / "tumble.bin", formats, rows)
    with pytest.raises(magfit.MagfitError) as unplaced:
        magfit.calibrate_file(path, "vector")
    assert "3-D GNSS" in str(unplaced.value)
    # Any place gives the reference (the model's field there): the place given is the one used.
    compass = magfit.calibrate_file(path, "vector", location=(47.4, 8.5, 0.5)).compasses[0]
    assert compass.calibration.method == "vector"
    assert any("reference field WMM" in note and "47.4°, 8.5°" in note for note in compass.notes)
