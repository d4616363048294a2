"""PX4's TC_Mn_* temperature compensation from the offset's drift, checked by PX4's own formula.

PX4 (TemperatureCompensation::calc_thermal_offsets_3D, calibration::Magnetometer): the temperature is clipped
to [TMIN, TMAX], dT = T - TREF, thermal_offset_i = X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3 (gauss, sensor
frame), subtracted from the raw reading with CAL_MAGn_OFF before the scale matrix (eq. P2, the pattern of PX4's
other sensors); and the magnetometer's Correct() as readable in PX4's source, which does not subtract it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import ExportError, OptionError
from magfit.export import export
from magfit.temperature import offset_drift

TRUE_OFFSET = np.array([12.0, -7.0, 21.0])  # µT, at 30 °C
TRUE_DRIFT = np.array([0.09, -0.06, 0.0])  # µT per °C: z does not drift


def _warming_tumble(seed: int = 3, n: int = 6000) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A tumble while the board warms from 20 to 45 °C: raw µT samples, temperatures, true directions, W."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    a = rng.normal(0, 0.05, (3, 3))
    soft = np.eye(3) + (a + a.T) / 2
    temperature = np.linspace(20.0, 45.0, n) + rng.normal(0, 0.1, n)
    offset = TRUE_OFFSET + np.outer(temperature - 30.0, TRUE_DRIFT)
    raw = 50.0 * directions @ soft.T + offset + rng.normal(0, 0.05, (n, 3))
    return raw, temperature, directions, soft


@pytest.fixture(scope="module")
def fitted() -> tuple[np.ndarray, np.ndarray, np.ndarray, magfit.Calibration]:
    raw, temperature, directions, _ = _warming_tumble()
    return raw, temperature, directions, magfit.fit(raw, method="ellipsoid").with_unit("uT")


def _parameters(text: str) -> dict[str, float]:
    rows = [line.split("\t") for line in text.splitlines() if line and not line.startswith("#")]
    return {name: float(value) for _, _, name, value, _ in rows}


def px4_correct(p: dict[str, float], raw_g: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """calc_thermal_offsets_3D then Magnetometer::Correct (R = identity, no power term), slot 0."""
    corrected_t = np.clip(temperature, p.get("TC_M0_TMIN", 0.0), p.get("TC_M0_TMAX", 100.0))
    dt = corrected_t - p.get("TC_M0_TREF", 25.0)
    thermal = np.zeros_like(raw_g)
    if p.get("TC_M_ENABLE", 0) == 1 and p.get("TC_M0_ID") == p.get("CAL_MAG0_ID"):
        for axis in range(3):
            thermal[:, axis] = sum(p[f"TC_M0_X{k}_{axis}"] * dt**k for k in range(4))
    off = np.array([p[f"CAL_MAG0_{a}OFF"] for a in "XYZ"])
    sc, od = [p[f"CAL_MAG0_{a}SCALE"] for a in "XYZ"], [p[f"CAL_MAG0_{a}ODIAG"] for a in "XYZ"]
    s = np.array([[sc[0], od[0], od[1]], [od[0], sc[1], od[2]], [od[1], od[2], sc[2]]])
    return (raw_g - thermal - off) @ s.T


def _angle_rms_deg(corrected: np.ndarray, truth: np.ndarray) -> float:
    unit = corrected / np.linalg.norm(corrected, axis=1)[:, None]
    return float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(np.sum(unit * truth, axis=1), -1, 1)) ** 2))))


def test_px4_applies_the_exported_drift_and_recovers_the_true_field(fitted: tuple) -> None:  # type: ignore[type-arg]
    raw, temperature, directions, calibration = fitted
    drift = offset_drift(raw, temperature, calibration)
    assert drift.determined
    np.testing.assert_allclose(drift.drift[:2], TRUE_DRIFT[:2], rtol=0.1)
    text = export(calibration, "px4", device_id=466441, temperature=drift)
    p = _parameters(text)
    assert p["TC_M_ENABLE"] == 1 and p["TC_M0_ID"] == 466441
    assert "\tTC_M_ENABLE\t1\t6" in text  # an INT32
    assert all(p[f"TC_M0_X{k}_{axis}"] == 0.0 for k in (0, 2, 3) for axis in range(3))
    np.testing.assert_allclose([p[f"TC_M0_X1_{a}"] for a in range(2)], 0.01 * TRUE_DRIFT[:2], rtol=0.1)
    assert p["TC_M0_X1_2"] == 0.0  # z: no drift, within two one-sigmas of zero, written as 0
    assert p["TC_M0_TMIN"] == pytest.approx(temperature.min(), abs=1e-3)
    assert p["TC_M0_TREF"] == pytest.approx(temperature.mean(), abs=1e-3)
    with_tc = _angle_rms_deg(px4_correct(p, raw * 0.01, temperature), directions)
    without = _angle_rms_deg(px4_correct({**p, "TC_M_ENABLE": 0}, raw * 0.01, temperature), directions)
    # the truth's own noise floor: 0.05 µT on 50 µT is 0.06 degrees
    assert with_tc < 0.15
    assert without > 5 * with_tc


def test_px4_clips_the_temperature_to_the_logs_range(fitted: tuple) -> None:  # type: ignore[type-arg]
    raw, temperature, _, calibration = fitted
    p = _parameters(export(calibration, "px4", device_id=7, temperature=offset_drift(raw, temperature, calibration)))
    hot = px4_correct(p, raw[:1] * 0.01, np.array([80.0]))
    at_max = px4_correct(p, raw[:1] * 0.01, np.array([p["TC_M0_TMAX"]]))
    np.testing.assert_allclose(hot, at_max)


def test_a_log_whose_temperature_does_not_vary_is_refused_with_the_reason(fitted: tuple) -> None:  # type: ignore[type-arg]
    raw, _, _, calibration = fitted
    flat = offset_drift(raw, np.full(len(raw), 31.0), calibration)
    with pytest.raises(ExportError) as refused:
        export(calibration, "px4", device_id=7, temperature=flat)
    assert refused.value.codes == ("undetermined",)
    assert "TC_M0_" in str(refused.value)


def test_without_a_device_id_or_in_another_format_it_is_refused(fitted: tuple) -> None:  # type: ignore[type-arg]
    raw, temperature, _, calibration = fitted
    drift = offset_drift(raw, temperature, calibration)
    with pytest.raises(OptionError, match="device_id"):
        export(calibration, "px4", temperature=drift)
    with pytest.raises(OptionError, match="applies to: px4"):
        export(calibration, "ardupilot", temperature=drift)


@pytest.mark.slow
def test_calibrate_writes_tc_m_from_a_ulog_that_warms_up(tmp_path: Path) -> None:
    from test_sources_ulog import ULogWriter
    from test_temperature import _warm_up

    truth = np.array([0.8, -0.5, 1.2])  # mG per °C
    raw, temperature = _warm_up(truth)
    writer = ULogWriter()
    fields = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z")]
    writer.format("sensor_mag", [*fields, ("float", "temperature")])
    writer.subscribe("sensor_mag", 0)
    for j, (sample, t) in enumerate(zip(raw / 1000.0, temperature, strict=True)):
        writer.data("sensor_mag", 0, 1_000_000 + 50_000 * j, 396809, *sample.tolist(), float(t))
    log = tmp_path / "warm.ulg"
    log.write_bytes(writer.bytes())
    out = tmp_path / "warm.params"
    result = CliRunner().invoke(cli, ["calibrate", str(log), "--export", "px4", "-o", str(out)])
    assert result.exit_code == 0, result.output
    p = _parameters(out.read_text())
    assert p["TC_M_ENABLE"] == 1 and p["TC_M0_ID"] == p["CAL_MAG0_ID"] == 396809
    slope = np.array([p[f"TC_M0_X1_{axis}"] for axis in range(3)])
    np.testing.assert_allclose(slope, truth / 1000.0, rtol=0.15)  # G per °C
    assert p["TC_M0_TMIN"] < p["TC_M0_TREF"] < p["TC_M0_TMAX"]


def px4_correct_ignoring_tc(p: dict[str, float], raw_g: np.ndarray) -> np.ndarray:
    """The magnetometer's Correct() as in the PX4 source readable: R (S ((raw + power COMP) - OFF)), the thermal
    offset fetched but not subtracted (R = identity, no power term), slot 0."""
    return px4_correct({**p, "TC_M_ENABLE": 0}, raw_g, np.zeros(len(raw_g)))


def test_a_firmware_that_ignores_tc_m_is_right_at_tref_and_off_by_the_stated_amount(fitted: tuple) -> None:  # type: ignore[type-arg]
    from magfit.export.px4_temperature import unapplied_offset

    raw, temperature, directions, calibration = fitted
    drift = offset_drift(raw, temperature, calibration)
    text = export(calibration, "px4", device_id=466441, temperature=drift)
    p = _parameters(text)
    slope = np.array([p[f"TC_M0_X1_{axis}"] for axis in range(3)])  # G per °C
    # the offset the firmware subtracts is OFF at every temperature: the true offset at T is off by X1 (T - TREF)
    true_offset_g = 0.01 * (TRUE_OFFSET + np.outer(temperature - 30.0, TRUE_DRIFT))
    off = np.array([p[f"CAL_MAG0_{a}OFF"] for a in "XYZ"])
    near_tref = np.abs(temperature - p["TC_M0_TREF"]) < 0.5
    # the whole log's offset is the offset at TREF (to the fit's noise, 0.3 mG)
    np.testing.assert_allclose(true_offset_g[near_tref].mean(axis=0), off, atol=3e-4)
    ends = np.array([p["TC_M0_TMIN"], p["TC_M0_TMAX"]])
    error_at_ends = np.linalg.norm(np.outer(ends - p["TC_M0_TREF"], 0.01 * TRUE_DRIFT), axis=1).max()
    stated = unapplied_offset(drift, slope)
    assert stated == pytest.approx(error_at_ends, rel=0.1)
    assert f"off by up to {1000 * stated:.1f} mG" in text
    # and the direction error it costs over the warm-up, against the compensation applied as (P2)
    ignored = _angle_rms_deg(px4_correct_ignoring_tc(p, raw * 0.01), directions)
    applied = _angle_rms_deg(px4_correct(p, raw * 0.01, temperature), directions)
    assert applied < 0.15 < 5 * applied < ignored
