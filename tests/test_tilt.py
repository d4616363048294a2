"""method="tilt": the calibration and the motors' field against the reference's horizontal strength and vertical
component at the logged roll and pitch, the yaw free. Every test with a truth compares against it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magfit
from magfit.errors import CalibrationError, OptionError
from magfit.motorsim import MotorFlight, simulate_motor_flight


def _wrong_yaw(flight: MotorFlight, offset_deg: float = 30.0, drift_deg: float = 20.0) -> np.ndarray:
    """The flight's attitude with its yaw wrong by ``offset_deg`` plus a slow drift (an EKF steered by the bad
    compass): roll and pitch kept."""
    error = np.radians(offset_deg + drift_deg * np.sin(flight.time_s / 60.0))
    return np.einsum("nij,njk->nik", Rotation.from_euler("z", error[:, None]).as_matrix(), flight.attitude)


def _tilt_error(flight: MotorFlight, sigma_deg: float, seed: int, time_s: float = 5.0) -> np.ndarray:
    """The attitude with a roll and pitch error correlated over ``time_s`` (Gauss-Markov, ``sigma_deg`` each)."""
    rng = np.random.default_rng(seed)
    step = float(np.median(np.diff(flight.time_s)))
    a = np.exp(-step / time_s)
    error = np.zeros((flight.time_s.size, 2))
    kick = rng.normal(0.0, np.sqrt(1 - a * a), error.shape)
    for i in range(1, error.shape[0]):
        error[i] = a * error[i - 1] + kick[i]
    turn = Rotation.from_euler("yx", np.radians(sigma_deg) * error).as_matrix()
    return np.einsum("nij,njk->nik", flight.attitude, turn)


def _inputs(flight: MotorFlight, attitude: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "reference": np.einsum("nji,j->ni", attitude, flight.field_ned),
        "down": attitude[:, 2, :],
    }


def _level_heading_error(calibration: magfit.Calibration, flight: MotorFlight) -> float:
    """RMS heading difference (degrees) between the calibration and the truth over the flight's samples, each
    turned level by the true attitude."""
    truth = flight.truth
    headings = []
    for cal in (calibration, truth):
        term = cal.motor
        if term is None:
            corrected = cal.apply(flight.samples)
        else:
            lag = flight.lag_s if cal is truth else term.lag_s
            source = flight.current if term.regressor == "current" else flight.throttle
            corrected = cal.apply(flight.samples, regressor=np.interp(flight.time_s - lag, flight.time_s, source))
        ned = np.einsum("nij,nj->ni", flight.attitude, corrected)
        headings.append(np.arctan2(ned[:, 1], ned[:, 0]))
    difference = np.angle(np.exp(1j * (headings[0] - headings[1])))
    return float(np.degrees(np.sqrt(np.mean(difference**2))))


@pytest.fixture(scope="module")
def flight() -> MotorFlight:
    return simulate_motor_flight(200, 10, driver="current", per_unit=4.0, seed=3)


def test_a_wrong_drifting_yaw_does_not_bias_it_and_the_motors_field_is_found(flight: MotorFlight) -> None:
    attitude = _wrong_yaw(flight)
    calibration = magfit.fit(
        flight.samples, method="tilt", **_inputs(flight, attitude),
        regressor=flight.current, regressor_time_s=flight.time_s, time_s=flight.time_s,
    )  # fmt: skip
    assert calibration.support is not None and calibration.support.verdict == "supported"
    assert calibration.frame == "vehicle" and calibration.method == "tilt"
    truth = flight.truth
    assert truth.motor is not None and calibration.motor is not None
    np.testing.assert_allclose(calibration.motor.coefficients, truth.motor.coefficients, atol=0.05)
    assert abs(calibration.motor.lag_s - flight.lag_s) <= 0.01
    np.testing.assert_allclose(calibration.offset, truth.offset, atol=3.0)  # mG, of offsets of ±150
    # The soft iron: the truth's correction scaled into the reference's unit (truth.matrix has det 1).
    scale = np.linalg.norm(flight.field_ned) / truth.field_strength
    np.testing.assert_allclose(calibration.matrix, truth.matrix * scale, atol=0.01)
    error = _level_heading_error(calibration, flight)
    uncertainty = calibration.diagnostics.uncertainty  # type: ignore[union-attr]
    assert uncertainty is not None and uncertainty.heading_sigma_deg is not None
    assert error < 0.1 and error < 4 * uncertainty.heading_sigma_deg
    # The whole attitude (vector) learns the yaw's error back.
    vector = magfit.fit(flight.samples, method="vector", reference=_inputs(flight, attitude)["reference"],
                        allow_undetermined=True)  # fmt: skip
    ned = np.einsum("nij,nj->ni", flight.attitude, vector.apply(flight.samples))
    assert np.degrees(np.std(np.unwrap(np.arctan2(ned[:, 1], ned[:, 0]) - np.arctan2(*flight.field_ned[1::-1])))) > 3


def test_without_the_regressor_the_motors_field_is_left_in_and_costs(flight: MotorFlight) -> None:
    calibration = magfit.fit(flight.samples, method="tilt", allow_undetermined=True, **_inputs(flight, flight.attitude))
    assert calibration.motor is None
    assert _level_heading_error(calibration, flight) > 1.0  # the 4 mG/A field, up to 40 % of the field, left in


def test_a_clean_vehicle_gets_no_term() -> None:
    clean = simulate_motor_flight(200, 10, driver="none", seed=5)
    calibration = magfit.fit(clean.samples, method="tilt", **_inputs(clean, clean.attitude), regressor=clean.current)
    assert calibration.motor is None
    facts = calibration.details["motor"]
    assert facts["percent"] < 2.0 and not facts["kept"]
    assert [reason["code"] for reason in facts["reasons"]] == ["motor_negligible"]
    assert _level_heading_error(calibration, clean) < 0.1


def test_a_current_that_follows_the_attitude_is_not_fitted() -> None:
    """A current that is a linear function of the vertical in the vehicle frame: its field ``k (a · d)`` is a soft
    iron's response to the vertical field, so it cannot be told from the matrix; no term may absorb it."""
    clean = simulate_motor_flight(200, 10, driver="none", seed=7)
    follows = 20.0 + 60.0 * clean.attitude[:, 2, 0] + 40.0 * clean.attitude[:, 2, 1]  # a · d, exactly
    calibration = magfit.fit(clean.samples, method="tilt", **_inputs(clean, clean.attitude), regressor=follows,
                             motor="current")  # fmt: skip
    facts = calibration.details["motor"]
    if calibration.motor is None:
        assert [reason["code"] for reason in facts["reasons"]] == ["motor_undetermined"]
    else:  # told from the attitude (S symmetric cannot take a rank-one k aᵀ): then it is the truth, nothing
        assert facts["independence"] >= 0.02 and facts["percent"] < 0.5
    assert _level_heading_error(calibration, clean) < 0.1
    auto = magfit.fit(clean.samples, method="tilt", **_inputs(clean, clean.attitude), regressor=follows)
    assert auto.motor is None  # motor="auto": nothing invented


def test_a_level_flight_through_few_headings_is_refused_with_the_reason() -> None:
    still = simulate_motor_flight(120, 10, driver="none", max_tilt_deg=0.5, seed=2)
    keep = np.abs(np.angle(np.exp(1j * (still.euler[:, 2] - still.euler[0, 2])))) < np.radians(15)
    if np.count_nonzero(keep) < 300:
        keep[:300] = True
    samples = still.samples[keep]
    attitude = still.attitude[keep]
    inputs = {"reference": np.einsum("nji,j->ni", attitude, still.field_ned), "down": attitude[:, 2, :]}
    with pytest.raises(CalibrationError) as refused:
        magfit.fit(samples, method="tilt", **inputs)
    assert "undetermined" in refused.value.codes
    assert "headings" in str(refused.value) or "roll and pitch" in str(refused.value)
    forced = magfit.fit(samples, method="tilt", **inputs, allow_undetermined=True)
    assert forced.support is not None and "undetermined" in forced.support.codes
    assert magfit.Calibration.from_json(forced.to_json()) == forced  # every figure of a refused fit is JSON


def test_bad_inputs_are_option_errors(flight: MotorFlight) -> None:
    inputs = _inputs(flight, flight.attitude)
    with pytest.raises(OptionError, match="down="):
        magfit.fit(flight.samples, method="tilt", reference=inputs["reference"])
    with pytest.raises(OptionError, match="not a unit vector"):
        magfit.fit(flight.samples, method="tilt", reference=inputs["reference"], down=inputs["down"] * 0.0 + 1e-3)
    with pytest.raises(OptionError, match="one value per sample"):
        magfit.fit(flight.samples, method="tilt", **inputs, regressor=flight.current[:-1])
    with pytest.raises(OptionError, match="time_s"):
        magfit.fit(flight.samples, method="tilt", **inputs, regressor=flight.current, regressor_time_s=flight.time_s)
    with pytest.raises(OptionError, match="motor must be"):
        magfit.fit(flight.samples, method="tilt", **inputs, motor="sometimes")


def test_json_round_trip_and_apply(flight: MotorFlight) -> None:
    calibration = magfit.fit(flight.samples, method="tilt", **_inputs(flight, flight.attitude),
                             regressor=flight.current)  # fmt: skip
    again = magfit.Calibration.from_json(calibration.to_json())
    assert again == calibration
    assert calibration.motor is not None
    corrected = calibration.apply(flight.samples, regressor=flight.current)
    # corrected = S (raw − V − k c): the one formula, here by hand.
    by_hand = flight.samples - calibration.offset - np.outer(flight.current, calibration.motor.coefficients)
    np.testing.assert_allclose(corrected, by_hand @ calibration.matrix.T, rtol=1e-12, atol=1e-9)


@pytest.mark.slow
def test_the_stated_one_sigma_covers_the_heading_error() -> None:
    """Over flights with 1° of roll and pitch error correlated over 5 s and a wrong yaw, the heading error
    against the truth over the stated one-sigma: RMS near 1 (not 10x more)."""
    ratios = []
    for seed in range(8):
        sim = simulate_motor_flight(200, 10, driver="current", seed=100 + seed)
        attitude = _tilt_error(sim, 1.0, seed)
        attitude = np.einsum("nij,njk->nik", _wrong_yaw(sim), np.einsum("nji,njk->nik", sim.attitude, attitude))
        calibration = magfit.fit(sim.samples, method="tilt", **_inputs(sim, attitude), regressor=sim.current,
                                 regressor_time_s=sim.time_s, time_s=sim.time_s, allow_undetermined=True)  # fmt: skip
        uncertainty = calibration.diagnostics.uncertainty  # type: ignore[union-attr]
        assert uncertainty is not None and uncertainty.heading_sigma_deg is not None
        ratios.append(_level_heading_error(calibration, sim) / uncertainty.heading_sigma_deg)
    rms = float(np.sqrt(np.mean(np.square(ratios))))
    assert 0.4 < rms < 1.6, ratios


def _log_with_fixes(path: Path, seed: int = 21) -> tuple[Path, MotorFlight]:
    """A simulated quad's DataFlash log (MAG, ATT, BAT, CTUN) with three 3-D fixes near Zurich in GPS week 2300
    (2024-02-04), its field the World Magnetic Model's there."""
    from magfit.geomag import field_at
    from test_motor_logs import write_flight
    from test_sources_dataflash import DataFlashWriter

    field = field_at(47.2, 8.5, 0.4885, date="2024-02-04").vector_in("mG")
    sim = simulate_motor_flight(200, driver="current", per_unit=3.0, seed=seed, field_ned=field)
    write_flight(path, sim, att=True)
    writer = DataFlashWriter()
    writer.define(140, "GPS", "QBBIHLLe", "TimeUS,I,Status,GMS,GWk,Lat,Lng,Alt")
    for j in range(3):
        writer.write("GPS", 2_000_000 + j, 0, 3, 100_000 + j * 200, 2300, 472000000, 85000000, 48850)
    path.write_bytes(path.read_bytes() + writer.bytes())
    return path, sim


@pytest.mark.slow
def test_calibrate_file_with_method_tilt_fits_the_current_jointly(tmp_path: Path) -> None:
    path, sim = _log_with_fixes(tmp_path / "quad.bin")
    result = magfit.calibrate_file(path, "tilt", motor="current")
    calibration = result.calibration
    assert calibration.method == "tilt" and calibration.motor is not None
    truth = sim.truth.motor
    assert truth is not None
    assert np.linalg.norm(calibration.motor.coefficients - truth.coefficients) < 0.1 * np.linalg.norm(
        truth.coefficients
    )
    assert any("fitted with the calibration" in note for note in result.compasses[0].notes)
    assert calibration.details["motor"]["chosen"] == "BAT.Curr"
    plain = magfit.calibrate_file(path, "tilt", motor="none", options={"allow_undetermined": True}).calibration
    assert plain.motor is None


def test_the_exports_reproduce_a_tilt_calibration_with_its_term(flight: MotorFlight) -> None:
    """The ArduPilot and PX4 parameters of a tilt calibration (vehicle frame, symmetric, with the current's term),
    applied by the firmwares' own formulas (re-implemented in tests/test_motor_export.py), give what apply gives."""
    from magfit.export import export
    from test_motor_export import ardupilot_correct, parse_ardupilot, px4_correct

    calibration = magfit.fit(flight.samples, method="tilt", **_inputs(flight, flight.attitude),
                             regressor=flight.current).with_unit("mG")  # fmt: skip
    assert calibration.motor is not None
    raw, current = flight.samples[::50], flight.current[::50]
    expected = calibration.apply(raw, regressor=current)
    params = parse_ardupilot(export(calibration, "ardupilot"))
    assert params["COMPASS_MOTCT"] == 2
    np.testing.assert_allclose(ardupilot_correct(params, raw, current), expected, rtol=0, atol=0.05)
    rows = [line.split("\t") for line in export(calibration, "px4").splitlines() if line and not line.startswith("#")]
    px4 = {row[2]: float(row[3]) for row in rows}
    assert px4["CAL_MAG_COMP_TYP"] == 2 and px4.get("CAL_MAG0_ROT", 0.0) == 0.0  # symmetric: no rotation written
    firmware = px4_correct(px4, 1e-3 * raw, current * 0.001)  # mG -> G; PX4's power is the current in kA
    np.testing.assert_allclose(firmware, 1e-3 * expected, rtol=0, atol=1e-4)


@pytest.mark.slow
def test_the_command_line_fits_it_says_the_term_and_exports_it(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from magfit.cli import cli

    path, _ = _log_with_fixes(tmp_path / "quad.bin", seed=22)
    out = tmp_path / "m.param"
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "tilt", "--motor", "current", "--export",
                                      "ardupilot", "-o", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "motors           the motors' field (current)" in result.output
    assert "fitted with the calibration" in result.output
    written = out.read_text()
    assert "COMPASS_MOTCT,2" in written and "COMPASS_MOT_Y," in written
