"""``auto`` on a boat (rolling on a held heading): refused, naming what works on a vehicle, and its forced
statement covering the truth; an ``auto`` fit's weakness never advises ``auto``.

The boat's samples fill a cap of about ±15° of field directions. A sensor with mild soft iron (±2 %) and one
with strong soft iron (±15 %) give the same kind of cap; the samples cannot tell them apart along the
directions the field never took, and the heading error of the magnitude-only fit differs tenfold between
them (the module's cases: about 1.5° and 4-22°). ``auto`` refuses both, its forced one-sigma covering each.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

import magfit
from magfit.vehicle import VehicleSimulation, simulate_vehicle


def _boat(seed: int, soft_iron_spread: float) -> VehicleSimulation:
    """A boat trial as the vehicle benchmark draws it: 6000 samples at 10 Hz, tilt ±15°, a random mounting."""
    rng = np.random.default_rng([seed, 7])
    spread = rng.normal(size=(3, 3)) * soft_iron_spread
    soft_iron = np.eye(3) + (spread + spread.T) / 2.0  # symmetric: the root a magnitude-only fit returns
    axis = rng.normal(size=3)
    mounting = Rotation.from_rotvec(np.radians(rng.uniform(5.0, 35.0)) * axis / np.linalg.norm(axis)).as_matrix()
    return simulate_vehicle(
        6000, "boat", rate_hz=10.0, soft_iron=soft_iron, hard_iron=rng.uniform(-0.4, 0.4, 3), mounting=mounting,
        inclination_deg=64.0, declination_deg=0.0, noise=0.005, max_tilt_deg=15.0, attitude_noise_deg=0.2,
        lag_s=0.1, seed=rng,
    )  # fmt: skip


def _heading_error_deg(calibration: magfit.Calibration, simulation: VehicleSimulation) -> float:
    """RMS heading error over the attitudes recorded, the true mounting applied to a sensor-frame fit (the
    best it can do): the calibrated body field turned into NED by the true attitude, against the true field."""
    body: NDArray[np.float64] = calibration.apply(simulation.clean)
    if calibration.frame != "vehicle":  # a vehicle-frame fit (vector) holds the mounting itself
        body = body @ simulation.mounting.T
    world = np.einsum("kij,kj->ki", simulation.attitude, body)
    truth = np.arctan2(simulation.field_world[1], simulation.field_world[0])
    error = (np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(error**2)))


@pytest.mark.parametrize(("seed", "spread"), [(0, 0.02), (1, 0.15)], ids=["mild soft iron", "strong soft iron"])
def test_auto_refuses_a_boat_naming_what_works_on_a_vehicle(seed: int, spread: float) -> None:
    simulation = _boat(seed, spread)
    with pytest.raises(magfit.CalibrationError) as refused:
        magfit.fit(simulation.samples, method="auto")
    assert set(refused.value.codes) & {"undetermined", "model_inadequate"}, refused.value.codes
    assert ("method", "vector") in refused.value.remedy
    # The words name every method that works on a vehicle (in the Python caller's words).
    for method in ("vector", "gyro", "sphere"):
        assert f"method='{method}'" in str(refused.value)
    forced = magfit.fit(simulation.samples, method="auto", allow_undetermined=True)
    assert forced.support is not None and forced.support.verdict == "refused"
    report = forced.diagnostics
    assert report is not None and report.uncertainty is not None and report.uncertainty.heading_sigma_deg is not None
    error = _heading_error_deg(forced, simulation)
    assert error <= report.uncertainty.heading_sigma_deg, (seed, error, report.uncertainty.heading_sigma_deg)
    # ... and the refusal is no bound 10x too wide on a mild sensor only: the strong one's error is real.
    if spread > 0.1:
        assert error > 3.0, error


def test_the_command_line_names_the_vehicle_methods_once_with_the_files_own_columns(tmp_path: Path) -> None:
    # The refusal's words for vehicles in general give way to the file's own advice (its columns named), so the
    # methods are said once; the vector method the advice names then runs on those columns.
    from click.testing import CliRunner

    from magfit.cli import cli

    simulation = _boat(0, 0.02)
    angles = Rotation.from_matrix(simulation.attitude_measured).as_euler("xyz", degrees=True)  # roll, pitch, yaw
    path = tmp_path / "boat.csv"
    rows = np.column_stack([simulation.time_s, simulation.samples, angles, np.tile(simulation.field_world, (6000, 1))])
    np.savetxt(path, rows, delimiter=",", header="time,mx,my,mz,roll,pitch,yaw,ref_n,ref_e,ref_d", comments="")
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "auto"])  # (the default fits it: vector)
    assert refused.exit_code == 1, refused.output
    assert refused.output.count("--method vector") == 1 and refused.output.count("--method gyro") == 1, refused.output
    vector = CliRunner().invoke(cli, ["calibrate", str(path), "--method", "vector", "-o", str(tmp_path / "cal.json")])
    assert vector.exit_code == 0, vector.output
    calibration = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    assert calibration.support is not None and calibration.support.verdict in ("supported", "weak")
    assert _heading_error_deg(calibration, simulation) < 1.0


def test_an_auto_fit_missing_soft_iron_is_not_told_to_use_auto(real_data_dir: Path) -> None:
    """apex5 tpu_00 (the accuracy benchmark's random half): auto keeps the diag model, weak, and the F test
    against the full ellipsoid names soft iron it misses: the advice names the full fit, never auto itself."""
    relative = "betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt"
    samples = np.loadtxt(real_data_dir / relative, delimiter=",", usecols=(0, 1, 2))
    order = np.random.default_rng([20261121, zlib.crc32(relative.encode())]).permutation(len(samples))
    calibration = magfit.fit(samples[order[: len(samples) // 2]], method="auto")
    assert calibration.support is not None and calibration.model != "full"
    named = [reason for reason in calibration.support.weaknesses if reason.code == "model_inadequate"]
    assert named, calibration.support.codes
    for reason in named:
        assert "auto method" not in reason
        assert "or auto" not in reason
    assert any("method='ml'" in reason for reason in named)


def test_the_vehicle_benchmark_judges_auto_where_it_answers_and_counts_its_refusals() -> None:
    """The vehicle benchmark's target: auto's stated one-sigma against its true-mounting error on the trials it
    answers (a refusal states nothing and is counted beside)."""
    import importlib
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    vehicle = importlib.import_module("accuracy_vehicle")
    car = vehicle.VehicleCase("car", "car", 1.0, 3)
    boat = vehicle.VehicleCase("boat", "boat", 1.0, 2)
    answered = [
        vehicle.VehicleOutcome(heading_mounted_deg=error, stated_heading_deg=stated)
        for error, stated in ((1.0, 2.0), (0.5, 1.0), (3.0, 2.0))
    ]
    refused = [vehicle.VehicleOutcome(error="refused")] * 2
    target = vehicle._auto_covered([car, boat], {"car": {"auto": answered}, "boat": {"auto": refused}})
    assert target.status == "FAIL" and "covered on 2/3 answered trials" in target.detail
    assert any("refused 2/2" in item for item in target.items)
    answered[2] = vehicle.VehicleOutcome(heading_mounted_deg=1.5, stated_heading_deg=2.0)
    target = vehicle._auto_covered([car, boat], {"car": {"auto": answered}, "boat": {"auto": refused}})
    assert target.status == "PASS"
