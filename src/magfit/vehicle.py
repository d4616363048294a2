"""A simulated vehicle in motion: what its magnetometer, gyroscope, accelerometer and attitude estimate report.

The magnitude-only simulator (:mod:`magfit.simulate`) draws attitudes; the methods that use what a vehicle
knows (a fit against a reference field, alignment from gravity, gyro-aided calibration) need a trajectory
in time, with the other sensors and their errors. The model, frames and conventions:

- world frame NED; body frame FRD (x forward, y right, z down); ``attitude[k]`` rotates body vectors into
  the world: ``v_world = attitude @ v_body`` (``Rz(yaw) Ry(pitch) Rx(roll)``, aerospace Z-Y-X angles);
- the Earth's field in the world ``f = B (cos δ cos D, cos δ sin D, sin δ)`` (inclination δ, declination D);
- the magnetometer is mounted with ``mounting`` (``v_body = mounting @ v_sensor``) and distorted by the soft
  iron W and hard iron V of the paper's eq. (1)::

      raw = W mountingᵀ attitudeᵀ f + V + noise = G r + V + noise,   r = attitudeᵀ f,  G = W mountingᵀ

  so the calibration that also aligns is ``corrected_body = G⁻¹ (raw − V)`` (:attr:`VehicleSimulation.truth`,
  frame ``"vehicle"``), and the magnitude-only one is ``W⁻¹ (raw − V)`` (:attr:`VehicleSimulation.truth_sensor`);
- the gyroscope and accelerometer sit in the body frame: ``gyro`` is the body rate (rad/s) plus a constant
  bias and white noise, ``accel`` the specific force ``attitudeᵀ (a − g)`` (m/s², −9.81 on z when level);
- the attitude estimate the vehicle logs lags by ``lag_s`` and carries an error of ``attitude_noise_deg`` per
  axis, correlated over ``attitude_noise_time_s`` (an estimator's error wanders; it is not white).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import Calibration
from .errors import OptionError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = ["MOTIONS", "VehicleSimulation", "simulate_vehicle"]

#: The trajectories :func:`simulate_vehicle` draws.
MOTIONS = ("flight", "car", "boat", "tumble", "yaw")
GRAVITY = 9.80665  # m/s², standard gravity
#: Internal time grid per sample: the lagged attitude is interpolated on it.
_OVERSAMPLING = 4


@dataclass(frozen=True, eq=False)
class VehicleSimulation:
    """A simulated recording of a vehicle and the truth behind it (see the module docstring for the frames).

    Attributes
    ----------
    time_s : ndarray, shape (N,)
        Sample times, seconds.
    samples, clean : ndarray, shape (N, 3)
        The magnetometer's raw field with and without noise, in the field's unit.
    attitude : ndarray, shape (N, 3, 3)
        The true body→world rotation at each sample.
    attitude_measured : ndarray, shape (N, 3, 3)
        What the vehicle's estimator logs: the attitude ``lag_s`` earlier, with its error.
    reference : ndarray, shape (N, 3)
        The field expected in the body frame from the measured attitude, ``attitude_measuredᵀ f``: what a
        fit against a reference field is given.
    gyro, accel : ndarray, shape (N, 3)
        Body rates (rad/s) and specific force (m/s²) in the body frame, with their errors.
    field_world : ndarray, shape (3,)
        The Earth's field in NED.
    mounting : ndarray, shape (3, 3)
        The magnetometer's rotation into the body frame.
    soft_iron, hard_iron : ndarray
        W (3, 3) and V (3,).
    truth : Calibration
        ``frame="vehicle"``: ``matrix = mounting W⁻¹``, so ``truth.apply(clean)`` is the body-frame field.
    truth_sensor : Calibration
        ``frame="sensor"``: ``matrix = W⁻¹``, the magnitude-only truth.
    lag_s, attitude_noise_deg : float
        The attitude's lag and error used.
    """

    time_s: NDArray[np.float64]
    samples: NDArray[np.float64]
    clean: NDArray[np.float64]
    attitude: NDArray[np.float64]
    attitude_measured: NDArray[np.float64]
    reference: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    field_world: NDArray[np.float64]
    mounting: NDArray[np.float64]
    soft_iron: NDArray[np.float64]
    hard_iron: NDArray[np.float64]
    truth: Calibration
    truth_sensor: Calibration
    lag_s: float
    attitude_noise_deg: float


def _rotation() -> type[Rotation]:
    from scipy.spatial.transform import Rotation  # not needed to import magfit

    return Rotation


def _smooth_noise(n: int, correlation_samples: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Unit-variance noise, (n, 3), correlated over ``correlation_samples`` (an AR(1) process; 0: white)."""
    white = rng.normal(size=(n, 3))
    if correlation_samples <= 1.0:
        return white
    from scipy.signal import lfilter

    keep = np.exp(-1.0 / correlation_samples)
    innovation = np.sqrt(1.0 - keep**2)
    # out[k] = keep·out[k−1] + innovation·white[k], starting at out[0] = white[0] (stationary from the start)
    start = (1.0 - innovation) * white[:1]
    return np.asarray(lfilter([innovation], [1.0, -keep], white, axis=0, zi=start)[0], dtype=np.float64)


def _euler_profile(motion: str, t: NDArray[np.float64], max_tilt_deg: float, speed: float,
                   rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Roll, pitch, yaw (rad) on the time grid ``t`` and the horizontal acceleration (m/s², NED), (n, 2)."""
    n = t.size
    dt = float(t[1] - t[0]) if n > 1 else 1.0
    tilt = np.radians(max_tilt_deg)
    zeros = np.zeros(n)
    acceleration = np.zeros((n, 2))
    if motion == "tumble":  # a hand-held tumble: every attitude, smoothly
        rates = [rng.uniform(0.05, 0.25) * 2 * np.pi * rng.choice([-1, 1]) for _ in range(3)]
        phases = rng.uniform(0, 2 * np.pi, 3)
        roll = rates[0] * t + phases[0]
        pitch = (np.pi / 2) * np.sin(rates[1] * t + phases[1])
        yaw = rates[2] * t + phases[2]
        return np.column_stack([roll, pitch, yaw]), acceleration
    if motion == "boat":  # rolling in waves, pitching a little, holding a heading that wanders slowly
        period = rng.uniform(5.0, 9.0)
        roll = tilt * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi))
        pitch = 0.25 * tilt * np.sin(2 * np.pi * t / (0.6 * period) + rng.uniform(0, 2 * np.pi))
        yaw = rng.uniform(-np.pi, np.pi) + np.radians(10.0) * np.sin(2 * np.pi * t / max(t[-1], dt) * 1.5)
        return np.column_stack([roll, pitch, yaw]), acceleration
    # Flight, car, yaw: straight legs and turns; the yaw rate is smoothed so the gyro sees no steps.
    legs = max(1, min(40, n // 50))
    leg_rate = np.where(rng.random(legs) < 0.3, 0.0, rng.uniform(-1.0, 1.0, legs))
    turn_rate = {"flight": np.radians(6.0), "car": np.radians(20.0), "yaw": np.radians(15.0)}[motion]  # rad/s
    rate = np.repeat(leg_rate, int(np.ceil(n / legs)))[:n] * turn_rate
    width = max(1, round(1.0 / dt))  # rate changes take about 4 s; smoothed twice, so the roll of a
    box = np.ones(2 * width + 1) / (2 * width + 1)  # coordinated turn (∝ rate) has no step in its own rate
    for _ in range(2):
        rate = np.convolve(np.pad(rate, width, mode="edge"), box, "valid")
    yaw = rng.uniform(-np.pi, np.pi) + np.cumsum(rate) * dt
    if motion == "yaw":
        return np.column_stack([zeros, zeros, yaw]), acceleration
    centripetal = speed * rate  # m/s² across the track, turning with the heading
    acceleration = centripetal[:, None] * np.column_stack([-np.sin(yaw), np.cos(yaw)])
    if motion == "flight":  # coordinated turns: the bank that holds the turn, pitch wandering within a third
        roll = np.clip(np.arctan2(centripetal, GRAVITY), -tilt, tilt)
        pitch = (tilt / 3.0) * np.sin(2 * np.pi * t / max(t[-1], dt) * rng.uniform(2.0, 5.0) + rng.uniform(0, 7))
        return np.column_stack([roll, pitch, yaw]), acceleration
    # car: road slopes and camber within the tilt, changing slowly
    slope = tilt * np.sin(2 * np.pi * t / max(t[-1], dt) * rng.uniform(3.0, 6.0) + rng.uniform(0, 7))
    camber = 0.5 * tilt * np.sin(2 * np.pi * t / max(t[-1], dt) * rng.uniform(4.0, 9.0) + rng.uniform(0, 7))
    return np.column_stack([camber, slope, yaw]), acceleration


def _body_rates(euler: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Body rates (p, q, r) from Z-Y-X Euler angles and their time derivatives (the kinematic equations)."""
    roll, pitch, _ = euler.T
    d_roll, d_pitch, d_yaw = np.gradient(euler, dt, axis=0).T
    p = d_roll - d_yaw * np.sin(pitch)
    q = d_pitch * np.cos(roll) + d_yaw * np.cos(pitch) * np.sin(roll)
    r = -d_pitch * np.sin(roll) + d_yaw * np.cos(pitch) * np.cos(roll)
    return np.column_stack([p, q, r])


def _matrices(euler: NDArray[np.float64]) -> NDArray[np.float64]:
    # Intrinsic Z-Y-X with the angles (yaw, pitch, roll): Rz(yaw) Ry(pitch) Rx(roll), body → world.
    return _rotation().from_euler("ZYX", euler[:, ::-1]).as_matrix()


def simulate_vehicle(
    n: int,
    motion: str = "flight",
    *,
    rate_hz: float = 50.0,
    soft_iron: ArrayLike | None = None,
    hard_iron: ArrayLike | None = None,
    mounting: ArrayLike | None = None,
    field_strength: float = 1.0,
    inclination_deg: float = 64.0,
    declination_deg: float = 0.0,
    noise: float = 0.0,
    max_tilt_deg: float = 15.0,
    speed: float = 25.0,
    attitude_noise_deg: float = 0.0,
    attitude_noise_time_s: float = 5.0,
    lag_s: float = 0.0,
    gyro_noise: float = 0.0,
    gyro_bias: ArrayLike | None = None,
    accel_noise: float = 0.0,
    seed: int | np.random.Generator | None = None,
) -> VehicleSimulation:
    """Simulate ``n`` samples at ``rate_hz`` of a vehicle in motion (frames in the module docstring).

    Parameters
    ----------
    n : int
        Number of samples (at least 10).
    motion : {"flight", "car", "boat", "tumble", "yaw"}
        ``"flight"``: straight legs and coordinated turns, roll up to ±``max_tilt_deg``, pitch within a
        third of it. ``"car"``: turns with road slopes and camber within the tilt. ``"boat"``: rolling in
        waves (±tilt) on a nearly constant heading. ``"tumble"``: every attitude, smoothly (a hand-held
        calibration). ``"yaw"``: level turns.
    soft_iron, hard_iron : array_like, optional
        W (3, 3) and V (3,) of eq. (1); identity and zero by default.
    mounting : array_like, shape (3, 3), optional
        The magnetometer's rotation into the body frame (identity by default). A proper rotation, or a
        mirror for a sensor with left-handed axes.
    field_strength, inclination_deg, declination_deg : float
        The Earth's field: B in the samples' unit, δ and D in degrees.
    noise : float
        Magnetometer noise per axis, in the field's unit.
    speed : float
        Ground speed, m/s (turn accelerations of flight and car).
    attitude_noise_deg, attitude_noise_time_s : float
        Error of the logged attitude per axis (degrees) and its correlation time (seconds; 0 is white).
    lag_s : float
        The logged attitude is that of ``lag_s`` seconds earlier.
    gyro_noise, gyro_bias, accel_noise : float / array_like
        Gyroscope white noise (rad/s) and constant bias (3,), accelerometer white noise (m/s²).
    seed : int or numpy Generator, optional
        Seed of the random draws.
    """
    if motion not in MOTIONS:
        raise OptionError(f"motion={motion!r} is not valid; choose one of: {', '.join(MOTIONS)}")
    if n < 10:
        raise OptionError(f"n must be at least 10, got {n}")
    if not rate_hz > 0 or not field_strength > 0:
        raise OptionError("rate_hz and field_strength must be positive")
    if min(noise, attitude_noise_deg, attitude_noise_time_s, gyro_noise, accel_noise) < 0:
        raise OptionError("noises and correlation times must be >= 0")
    rng = np.random.default_rng(seed)
    w = np.eye(3) if soft_iron is None else np.asarray(soft_iron, dtype=np.float64)
    v = np.zeros(3) if hard_iron is None else np.asarray(hard_iron, dtype=np.float64)
    mount = np.eye(3) if mounting is None else np.asarray(mounting, dtype=np.float64)
    if w.shape != (3, 3) or abs(np.linalg.det(w)) < 1e-12:
        raise OptionError("soft_iron must be an invertible 3x3 matrix")
    if v.shape != (3,):
        raise OptionError(f"hard_iron must have shape (3,), got {v.shape}")
    if mount.shape != (3, 3) or not np.allclose(mount @ mount.T, np.eye(3), atol=1e-9):
        raise OptionError("mounting must be a 3x3 rotation (orthonormal) matrix")

    # The trajectory on a finer grid that reaches lag_s before the first sample: the lagged attitude and
    # the body rates are read from it.
    dt = 1.0 / rate_hz
    fine_dt = dt / _OVERSAMPLING
    lead = int(np.ceil(max(lag_s, 0.0) / fine_dt)) + 1
    fine_t = (np.arange(n * _OVERSAMPLING + lead, dtype=np.float64) - lead) * fine_dt
    euler, horizontal = _euler_profile(motion, fine_t, max_tilt_deg, speed, rng)
    euler[:, 2] = np.unwrap(euler[:, 2])
    time_s = np.arange(n, dtype=np.float64) * dt
    at_samples = lead + np.arange(n) * _OVERSAMPLING

    attitude = _matrices(euler[at_samples])
    rates = _body_rates(euler, fine_dt)[at_samples]
    lagged = np.column_stack([np.interp(time_s - lag_s, fine_t, euler[:, i]) for i in range(3)])
    attitude_measured = _matrices(lagged)
    if attitude_noise_deg > 0:
        error = np.radians(attitude_noise_deg) * _smooth_noise(n, attitude_noise_time_s * rate_hz, rng)
        attitude_measured = attitude_measured @ _rotation().from_rotvec(error).as_matrix()

    inclination, declination = np.radians(inclination_deg), np.radians(declination_deg)
    field_world = field_strength * np.array(
        [np.cos(inclination) * np.cos(declination), np.cos(inclination) * np.sin(declination), np.sin(inclination)]
    )
    body_field = np.einsum("kji,j->ki", attitude, field_world)  # attitudeᵀ f
    reference = np.einsum("kji,j->ki", attitude_measured, field_world)
    g = w @ mount.T
    clean = body_field @ g.T + v
    samples = clean + rng.normal(0.0, noise, clean.shape) if noise > 0 else clean.copy()

    bias = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, dtype=np.float64)
    gyro = rates + bias + (rng.normal(0.0, gyro_noise, rates.shape) if gyro_noise > 0 else 0.0)
    world_acceleration = np.column_stack([horizontal[at_samples], np.zeros(n)])
    specific_force = world_acceleration - np.array([0.0, 0.0, GRAVITY])
    accel = np.einsum("kji,kj->ki", attitude, specific_force)
    if accel_noise > 0:
        accel = accel + rng.normal(0.0, accel_noise, accel.shape)

    truth = Calibration(
        "truth", v, np.asarray(mount @ np.linalg.inv(w), dtype=np.float64), field_strength, frame="vehicle"
    )
    truth_sensor = Calibration("truth", v, np.asarray(np.linalg.inv(w), dtype=np.float64), field_strength)
    return VehicleSimulation(
        time_s, samples, clean, attitude, attitude_measured, reference, gyro, accel, field_world, mount, w, v,
        truth, truth_sensor, float(lag_s), float(attitude_noise_deg),
    )  # fmt: skip
