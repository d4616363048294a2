"""The offset's drift with temperature: a simulated warm-up with a known drift per °C recovered within its stated
one-sigma; a constant temperature refused with its code; the ULog's sensor_mag.temperature read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.errors import SampleError
from magfit.temperature import offset_drift, read_mag_temperature
from magfit.vehicle import simulate_vehicle
from test_sources_ulog import ULogWriter

SOFT = np.array([[1.10, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.0]])
HARD = np.array([120.0, -60.0, 200.0])


def _warm_up(drift, *, rise=25.0, seed=1):
    sim = simulate_vehicle(4000, "tumble", rate_hz=20.0, field_strength=480.0, inclination_deg=60.0, seed=seed)
    body = np.einsum("nji,j->ni", sim.attitude, sim.field_world)
    temperature = 20.0 + rise * (1 - np.exp(-sim.time_s / 60.0))  # a warm-up from 20 °C
    rng = np.random.default_rng(seed)
    tau = temperature - temperature.mean()
    raw = body @ SOFT.T + HARD + np.outer(tau, drift) + rng.normal(0, 1.5, body.shape)
    return raw, temperature


@pytest.mark.slow
def test_a_known_drift_is_recovered_within_its_stated_sigma() -> None:
    truth = np.array([0.8, -0.5, 1.2])  # mG per °C
    raw, temperature = _warm_up(truth)
    calibration = magfit.fit(raw, method="ellipsoid")
    drift = offset_drift(raw, temperature, calibration)
    assert drift.determined and drift.reasons == ()
    assert np.all(np.abs(drift.drift - truth) <= np.maximum(3 * drift.sigma, 0.05))
    assert np.all(np.abs(drift.drift - truth) < 0.15 * np.abs(truth))
    none = offset_drift(*_warm_up(np.zeros(3), seed=2), magfit.fit(_warm_up(np.zeros(3), seed=2)[0]))
    assert np.all(np.abs(none.drift) <= np.maximum(3 * none.sigma, 0.05))  # no drift invented


def test_a_constant_temperature_determines_no_drift() -> None:
    raw, temperature = _warm_up(np.zeros(3), rise=0.5)
    drift = offset_drift(raw, temperature, magfit.fit(raw, method="ellipsoid"))
    assert not drift.determined and [r.code for r in drift.reasons] == ["undetermined"]
    assert np.all(np.isnan(drift.drift))
    with pytest.raises(SampleError, match="temperatures"):
        offset_drift(raw, temperature[:-1], magfit.fit(raw))


def test_the_ulog_temperature_is_read(tmp_path: Path) -> None:
    writer = ULogWriter()
    fields = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z")]
    writer.format("sensor_mag", [*fields, ("float", "temperature")])
    writer.subscribe("sensor_mag", 0)
    for j in range(50):
        writer.data("sensor_mag", 0, 1_000_000 + 20_000 * j, 7, 0.2, 0.1, 0.4, 30.0 + 0.1 * j)
    log = tmp_path / "t.ulg"
    log.write_bytes(writer.bytes())
    read = read_mag_temperature(log, "sensor_mag/0")
    assert read is not None
    time_s, temperature = read
    np.testing.assert_allclose(temperature, 30.0 + 0.1 * np.arange(50), atol=1e-5)
    np.testing.assert_allclose(time_s, 1.0 + 0.02 * np.arange(50))
    assert read_mag_temperature(log, "sensor_mag/1") is None


@pytest.mark.slow
def test_log_drifts_reads_a_ulog_warm_up(tmp_path: Path) -> None:
    from magfit.temperature import log_drifts

    truth = np.array([0.8, -0.5, 1.2]) / 1000  # G per °C
    raw, temperature = _warm_up(truth * 1000)
    raw = raw / 1000  # gauss, as PX4 logs sensor_mag
    writer = ULogWriter()
    fields = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z")]
    writer.format("sensor_mag", [*fields, ("float", "temperature")])
    writer.subscribe("sensor_mag", 0)
    for j in range(len(raw)):
        writer.data("sensor_mag", 0, 1_000_000 + 50_000 * j, 7, *raw[j], temperature[j])
    log = tmp_path / "warm.ulg"
    log.write_bytes(writer.bytes())
    result = magfit.calibrate_file(log, "ellipsoid")
    (drift,) = log_drifts(result).values()
    assert drift.determined and drift.unit == "G"
    assert np.all(np.abs(drift.drift - truth) <= np.maximum(3 * drift.sigma, 5e-5))
