"""The motors' field: the joint fit (docs/methods.md eq. M1-M4), the term a calibration holds, its JSON."""

from __future__ import annotations

import numpy as np
import pytest

import magfit
from magfit import Calibration
from magfit.errors import DataFileError, SampleError
from magfit.motor import fit_motor, with_motor
from magfit.motorsim import heading_error_deg, simulate_motor_flight
from magfit.motorterm import MotorTerm


def _base(samples: np.ndarray) -> Calibration:
    return magfit.fit(samples, method="auto", allow_undetermined=True).with_unit("mG")


def _heading(calibration: Calibration, flight, regressor) -> float:
    corrected = (
        calibration.apply(flight.samples, regressor=regressor)
        if calibration.motor
        else calibration.apply(flight.samples)
    )
    return heading_error_deg(corrected, flight.attitude, flight.field_ned)


@pytest.mark.parametrize("driver", ["current", "throttle"])
@pytest.mark.slow
def test_joint_fit_recovers_the_term_and_the_heading(driver: str) -> None:
    flight = simulate_motor_flight(200, driver=driver, per_unit=4.0 if driver == "current" else 150.0, seed=3)
    signal = flight.current if driver == "current" else flight.throttle
    base = _base(flight.samples)
    result = fit_motor(flight.samples, base, signal, kind=driver, time_s=flight.time_s, regressor_time_s=flight.time_s)
    assert result.fitted and result.term is not None
    truth = flight.truth.motor
    assert truth is not None
    assert np.linalg.norm(result.term.coefficients - truth.coefficients) < 0.06 * np.linalg.norm(truth.coefficients)
    assert abs(result.term.lag_s - flight.lag_s) <= 0.021
    lagged = np.interp(flight.time_s - result.term.lag_s, flight.time_s, signal)
    final = with_motor(result, flight.samples, lagged, _base)
    true_lagged = np.interp(flight.time_s - flight.lag_s, flight.time_s, signal)
    assert _heading(final, flight, lagged) <= 1.5 * _heading(flight.truth, flight, true_lagged)
    assert _heading(base, flight, None) > 3 * _heading(flight.truth, flight, true_lagged)  # the term matters here


def test_clean_vehicle_invents_no_term() -> None:
    flight = simulate_motor_flight(200, driver="none", seed=4)
    base = _base(flight.samples)
    result = fit_motor(flight.samples, base, flight.current, time_s=flight.time_s, regressor_time_s=flight.time_s)
    assert not result.fitted
    assert result.calibration is base
    assert [reason.code for reason in result.reasons] == ["motor_negligible"]
    assert result.percent < 2.0


def test_current_that_follows_the_attitude_is_undetermined() -> None:
    """A current that is a function of the field's direction in the sensor (peak current at one heading)
    cannot be told from the soft iron: never absorbed into the coefficients."""
    flight = simulate_motor_flight(200, driver="none", seed=5)
    direction = flight.samples - flight.truth.offset
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    current = 25.0 + 20.0 * direction[:, 0]
    k = np.array([2.0, -1.0, 3.0])
    samples = flight.samples + np.outer(current, k)
    result = fit_motor(samples, _base(samples), current, motor="current")
    assert not result.fitted
    assert [reason.code for reason in result.reasons] == ["motor_undetermined"]
    assert result.independence < 0.02


def test_constant_current_is_refused() -> None:
    flight = simulate_motor_flight(60, driver="none", seed=6)
    result = fit_motor(flight.samples, _base(flight.samples), np.full(len(flight.samples), 12.0), motor="current")
    assert not result.fitted and result.term is None
    assert [reason.code for reason in result.reasons] == ["motor_undetermined"]


@pytest.mark.slow
def test_motor_none_reports_but_keeps_nothing() -> None:
    flight = simulate_motor_flight(120, driver="current", seed=7)
    result = fit_motor(flight.samples, _base(flight.samples), flight.current, motor="none")
    assert not result.fitted and result.term is not None
    assert result.percent > 20


def test_apply_with_regressor_matches_the_formula() -> None:
    term = MotorTerm("current", [1.0, -2.0, 0.5], lag_s=0.02, full_scale=40.0)
    calibration = Calibration("x", [1.0, 2.0, 3.0], np.diag([1.1, 0.9, 1.0 / 0.99]), 500.0, unit="mG", motor=term)
    raw = np.array([[100.0, 200.0, 300.0], [-50.0, 10.0, 400.0]])
    current = np.array([10.0, 30.0])
    expected = (raw - calibration.offset - np.outer(current, term.coefficients)) @ calibration.matrix.T
    np.testing.assert_allclose(calibration.apply(raw, regressor=current), expected, rtol=1e-12)
    with pytest.raises(SampleError):
        calibration.apply(raw)  # the term needs its regressor
    with pytest.raises(SampleError):
        Calibration.identity().apply(raw, regressor=current)
    np.testing.assert_array_equal(Calibration.identity().apply(raw), raw)


def test_json_round_trip_is_lossless_and_old_files_read() -> None:
    term = MotorTerm("throttle", [0.1, 0.2, 0.30000000000000004], lag_s=-0.01, full_scale=1.0)
    calibration = Calibration("x", [1.0, 2.0, 3.0], np.eye(3), 500.0, unit="mG", motor=term)
    again = Calibration.from_json(calibration.to_json())
    assert again == calibration and again.motor == term
    plain = Calibration("x", [1.0, 2.0, 3.0], np.eye(3), 500.0)
    assert "motor" not in plain.to_dict()  # files without a term are written as before
    assert Calibration.from_json(plain.to_json()).motor is None
    broken = calibration.to_dict()
    broken["motor"]["coefficients"] = [1, 2]
    with pytest.raises(DataFileError, match="motor"):
        Calibration.from_dict(broken)
    broken["motor"] = {"regressor": "rpm", "coefficients": [1, 2, 3]}
    with pytest.raises(DataFileError, match="motor"):
        Calibration.from_dict(broken)
