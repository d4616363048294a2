"""A simulated vehicle's recording as the samples file a user brings (shared by the tests that need one).

The vehicle: field 50 µT at 60° inclination and 5° declination, soft and hard iron drawn from ``seed``, a mounting
of a few degrees, attitude noise 0.5° lagging 20 ms, gyro noise and bias, accelerometer noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from magfit.vehicle import VehicleSimulation, simulate_vehicle


def simulated_vehicle(motion: str, seed: int, n: int = 3000) -> VehicleSimulation:
    """The vehicle in ``motion`` ("car", "boat", "flight", "tumble", ...): its recording and its truth."""
    rng = np.random.default_rng(seed)
    w = np.eye(3) + rng.normal(0, 0.08, (3, 3))
    return simulate_vehicle(
        n, motion, soft_iron=(w + w.T) / 2, hard_iron=rng.normal(0, 0.5, 3) * 50,
        mounting=Rotation.from_euler("xyz", rng.normal(0, 5, 3), degrees=True).as_matrix(), field_strength=50.0,
        inclination_deg=60, declination_deg=5, noise=0.3, attitude_noise_deg=0.5, gyro_noise=0.002,
        gyro_bias=[0.01, -0.005, 0.003], accel_noise=0.05, lag_s=0.02, seed=seed,
    )  # fmt: skip


def vehicle_recording(motion: str, seed: int, n: int = 3000) -> tuple[VehicleSimulation, dict[str, np.ndarray]]:
    """:func:`simulated_vehicle` and its columns: time s, mx..mz µT, roll/pitch/yaw degrees (body to NED),
    reference N/E/D, gyro rad/s, accel m/s²."""
    sim = simulated_vehicle(motion, seed, n)
    ypr = Rotation.from_matrix(sim.attitude_measured).as_euler("ZYX", degrees=True)
    ref = np.tile(sim.field_world, (len(sim.samples), 1))
    names = "time mx my mz roll pitch yaw ref_n ref_e ref_d gx gy gz ax ay az".split()
    values = [sim.time_s, *sim.samples.T, ypr[:, 2], ypr[:, 1], ypr[:, 0], *ref.T, *sim.gyro.T, *sim.accel.T]
    return sim, dict(zip(names, values, strict=True))


def save_columns(path: Path, columns: dict[str, np.ndarray]) -> Path:
    """``columns`` as a CSV with their names for header; ``path``."""
    np.savetxt(path, np.column_stack(list(columns.values())), fmt="%.6f", delimiter=",", header=",".join(columns),
               comments="")  # fmt: skip
    return path
