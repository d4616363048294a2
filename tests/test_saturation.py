"""Samples clipped at the sensor's full scale are found, left out and counted, or the fit is refused.

The reproducer: a sensor whose field plus offset reaches past its full scale (here 1.4 times the field,
the offset 0.8 times) reports the range's end on that axis. Kept, those rows pulled ellipsoid, als, ml,
auto and diag to several degrees of heading error while "supported"; an int8 recording pinned at
±127/−128 on nearly every row came back "weak" while 176° off.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import magfit
from magfit.saturation import find_clipped

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _common import heading_error_deg

FULL_SCALE = 1.4  # field strengths


def _clipped_sensor(seed: int, n: int = 2000) -> tuple[magfit.Simulation, np.ndarray]:
    rng = np.random.default_rng(seed)
    soft = np.eye(3) + rng.uniform(-0.1, 0.1, (3, 3))
    offset = 0.8 * rng.choice([-1.0, 1.0], 3) * rng.uniform(0.5, 1.0, 3)
    sim = magfit.simulate(n, soft_iron=(soft + soft.T) / 2, hard_iron=offset, noise=0.01, seed=seed)
    return sim, np.clip(sim.samples, -FULL_SCALE, FULL_SCALE)


@pytest.mark.parametrize("method", ["ellipsoid", "als", "ml", "auto"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clipped_rows_are_left_out_counted_and_named(method: str, seed: int) -> None:
    sim, samples = _clipped_sensor(seed)
    truly_clipped = np.any(np.abs(sim.samples) > FULL_SCALE, axis=1)
    calibration = magfit.fit(samples, method)
    recorded = calibration.details["saturation"]
    assert recorded["n_clipped"] == int(truly_clipped.sum()), (seed, recorded)
    assert calibration.n_samples == samples.shape[0] - recorded["n_clipped"]
    support = calibration.support
    assert support.verdict == "weak" and "saturated" in support.codes, support
    error = heading_error_deg(calibration, sim)
    stated = calibration.diagnostics.uncertainty.heading_sigma_deg  # type: ignore[union-attr]
    assert error <= 3.0 * stated, (seed, method, error, stated)  # before: 1-8° off, stating ±0.3-0.5°


def test_an_int8_recording_pinned_at_full_scale_is_refused_naming_the_range() -> None:
    sim = magfit.simulate(300, hard_iron=[20.0, -30.0, 10.0], field_strength=250.0, noise=1.0, seed=4)
    samples = np.clip(np.round(sim.samples), -128, 127).astype(np.int8)
    assert np.sum(np.any((samples == 127) | (samples == -128), axis=1)) >= 295
    for method in ("ellipsoid", "auto", "sphere", "minmax", "robust"):
        with pytest.raises(magfit.CalibrationError, match="full-scale range") as caught:
            magfit.fit(samples, method)
        assert caught.value.codes == ("saturated",), (method, caught.value.codes)


def test_full_scale_codes_of_integer_sensors_count_when_held_twice() -> None:
    sim = magfit.simulate(1500, hard_iron=[20000.0, 0.0, 0.0], field_strength=15000.0, noise=20.0, seed=1)
    samples = np.clip(np.round(sim.samples), -32768, 32767)
    clipping = find_clipped(samples)
    assert clipping.n_clipped == int(np.sum(samples[:, 0] == 32767)) > 0
    assert clipping.ends[0][:2] == ("x", 32767.0)


@pytest.mark.parametrize(
    "make",
    [
        lambda sim: sim.samples,  # float, unclipped
        lambda sim: np.round(sim.samples * 20.0),  # coarse integer counts: every level near the end is full
        lambda sim: np.repeat(sim.samples, 10, axis=0),  # sample-and-hold: every value held alike
    ],
    ids=["float", "quantised", "held"],
)
def test_unclipped_recordings_are_left_whole(make) -> None:  # type: ignore[no-untyped-def]
    sim = magfit.simulate(3000, hard_iron=[0.3, -0.2, 0.5], noise=0.01, seed=3)
    samples = make(sim)
    assert find_clipped(samples).n_clipped == 0
    assert "saturation" not in magfit.fit(samples, "ellipsoid", diagnostics=False).details


def test_the_real_recordings_hold_no_clipped_rows(real_data_dir: Path) -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from test_real_recordings import load

    names = "fxos unc betaflight03 betaflight00 mxl_imu mxl_pni mxl_drone gyrolib hamagure1 ensta android hmc5883l"
    for name in names.split():
        assert find_clipped(load(real_data_dir, name)).n_clipped == 0, name
