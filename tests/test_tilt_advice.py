"""A vehicle's refused recording names ``tilt`` where it holds an attitude (roll and pitch logged, the yaw
suspect), never where it holds none, and the command named runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

import magfit
from magfit.cli import cli
from magfit.pipeline.advice import vehicle_advice
from magfit.vehicle import simulate_vehicle


def _methods(advice: tuple[object, ...]) -> list[str]:
    return [dict(reason.remedy)["method"] for reason in advice]  # type: ignore[attr-defined]


def test_tilt_is_advised_where_the_recording_has_an_attitude() -> None:
    path = Path("car.csv")
    with_attitude = vehicle_advice(path, is_log=False, streams=("attitude", "reference"), unit="uT", method="sphere")
    assert _methods(with_attitude) == ["vector", "tilt", "gyro", "sphere"]
    tilt = with_attitude[1]
    assert tilt.code == "vehicle_methods" and dict(tilt.remedy) == {"method": "tilt", "unit": "uT"}
    without = vehicle_advice(path, is_log=False, streams=("gyro", "time"), unit="uT", method="sphere")
    assert "tilt" not in _methods(without)
    # A refused vector fit of a log names tilt first; a refused tilt does not name itself.
    log = vehicle_advice(path, is_log=True, streams=("attitude", "place", "gyro", "time"), unit="uT", method="vector")
    assert _methods(log)[0] == "tilt"
    assert "tilt" not in _methods(vehicle_advice(path, is_log=True, streams=("attitude",), unit="uT", method="tilt"))


def test_the_tilt_command_named_by_a_refusal_calibrates_against_the_truth(tmp_path: Path) -> None:
    sim = simulate_vehicle(
        1500, "car", soft_iron=np.diag([1.05, 0.97, 1.0]), hard_iron=[12.0, -7.0, 20.0], field_strength=50.0,
        inclination_deg=60, declination_deg=5, noise=0.3, attitude_noise_deg=0.3, seed=4,
    )  # fmt: skip
    yaw, pitch, roll = Rotation.from_matrix(sim.attitude_measured).as_euler("ZYX", degrees=True).T
    ref = np.tile(sim.field_world, (len(sim.samples), 1))
    path = tmp_path / "car.csv"
    np.savetxt(path, np.column_stack([sim.time_s, sim.samples, roll, pitch, yaw, ref]), fmt="%.6f", delimiter=",",
               header="time,mx,my,mz,roll,pitch,yaw,ref_n,ref_e,ref_d", comments="")  # fmt: skip
    refused = CliRunner().invoke(cli, ["calibrate", str(path), "--unit", "uT", "--method", "sphere"])
    assert refused.exit_code == 1, refused.output
    command = f"magfit calibrate {path} --method tilt --unit uT"
    assert command in refused.output.replace("\n", " ")
    cal = tmp_path / "cal.json"
    run = CliRunner().invoke(cli, [*command.split()[1:], "-o", str(cal)])
    assert run.exit_code == 0, run.output
    fitted = magfit.Calibration.from_json(cal.read_text())
    # tilt keeps the compass's frame (no rotation fitted): the heading of the corrected clean samples, turned by
    # the true attitude, against the truth's, within 3 stated one-sigmas.
    world = np.einsum("kij,kj->ki", sim.attitude, fitted.apply(sim.clean))
    truth = np.arctan2(sim.field_world[1], sim.field_world[0])
    error = float(np.sqrt(np.mean(((np.degrees(np.arctan2(world[:, 1], world[:, 0]) - truth) + 180) % 360 - 180) ** 2)))
    assert error < 3 * fitted.diagnostics.uncertainty.heading_sigma_deg, error
