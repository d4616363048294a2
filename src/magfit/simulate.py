"""A simulator of the paper's measurement model (eq. 1), and the paper's experiment as named scenarios.

    B_p = W R_x(φ) R_y(θ) R_z(ψ) B (cos δ, 0, sin δ)ᵀ + V                        (1)

W is the soft-iron matrix, V the hard-iron offset, B the field strength, δ the inclination and
(φ, θ, ψ) the roll, pitch and yaw of the sensor. A vehicle's own field adds, in Tolles–Lawson's
aeromagnetic compensation (Tolles & Lawson, "Magnetic compensation of MAD equipped aircraft", 1950), a
permanent term (V), an induced term proportional to the direction cosines of the field (W − I), and an
eddy-current term proportional to their rate of change:

    B_p(t) = W b(t) + V + E ḃ(t),    b = R_x(φ) R_y(θ) R_z(ψ) B (cos δ, 0, sin δ)ᵀ           (1e)

E (seconds) follows the manoeuvres: no calibration of eq. (1) holds it. Gaussian noise of standard
deviation ``noise`` is added to each axis of B_p, then the result is optionally quantised (raw counts).
The true calibration is ``offset = V``, ``matrix = W⁻¹``, ``field_strength = B``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import Calibration

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation
from .errors import OptionError

__all__ = [
    "DISTURBANCES",
    "ORIENTATIONS",
    "SENSORS",
    "Scenario",
    "Simulation",
    "rotation_matrices",
    "scenario",
    "simulate",
]

ORIENTATIONS = ("uniform", "restricted", "yaw", "flight")


def _rotation() -> type[Rotation]:
    """scipy's Rotation, imported on first use (it is not needed to import magfit)."""
    from scipy.spatial.transform import Rotation

    return Rotation


def rotation_matrices(attitudes_deg: ArrayLike) -> NDArray[np.float64]:
    """``R_x(φ) R_y(θ) R_z(ψ)`` of eq. (1) for each row (roll φ, pitch θ, yaw ψ) in degrees; (N, 3, 3)."""
    angles = np.radians(np.atleast_2d(np.asarray(attitudes_deg, dtype=np.float64)))
    # Intrinsic X-Y-Z Euler angles compose exactly as the product R_x R_y R_z.
    return _rotation().from_euler("XYZ", angles).as_matrix()


@dataclass(frozen=True, eq=False)
class Simulation:
    """Simulated samples and the truth behind them.

    Attributes
    ----------
    samples : ndarray, shape (N, 3)
        What the sensor reports: eq. (1) plus noise (and quantisation), input units.
    clean : ndarray, shape (N, 3)
        The same without noise or quantisation.
    attitudes : ndarray, shape (N, 3)
        Roll φ, pitch θ, yaw ψ of each sample, degrees.
    truth : Calibration
        The calibration that maps ``clean`` exactly onto the sphere of radius B.
    soft_iron, hard_iron, field_strength, inclination_deg
        The parameters W, V, B, δ of eq. (1).
    """

    samples: NDArray[np.float64]
    clean: NDArray[np.float64]
    attitudes: NDArray[np.float64]
    truth: Calibration
    soft_iron: NDArray[np.float64]
    hard_iron: NDArray[np.float64]
    field_strength: float
    inclination_deg: float

    def distort(self, attitudes_deg: ArrayLike) -> NDArray[np.float64]:
        """Noise-free readings of this simulated sensor at the given attitudes, shape (N, 3)."""
        return _model(attitudes_deg, self.soft_iron, self.hard_iron, self.field_strength, self.inclination_deg)


def _model(
    attitudes_deg: ArrayLike,
    soft_iron: NDArray[np.float64],
    hard_iron: NDArray[np.float64],
    field_strength: float,
    inclination_deg: float,
) -> NDArray[np.float64]:
    delta = np.radians(inclination_deg)
    earth_field = field_strength * np.array([np.cos(delta), 0.0, np.sin(delta)])
    in_sensor_frame = rotation_matrices(attitudes_deg) @ earth_field  # R_x R_y R_z B (cos δ, 0, sin δ)ᵀ
    return in_sensor_frame @ soft_iron.T + hard_iron  # W (...) + V


def _attitudes(
    n: int, orientations: str | ArrayLike, max_tilt_deg: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    if not isinstance(orientations, str):
        attitudes = np.asarray(orientations, dtype=np.float64)
        if attitudes.shape != (n, 3):
            raise OptionError(f"orientations must be one of {ORIENTATIONS} or an ({n}, 3) array of degrees")
        return attitudes
    if orientations == "uniform":  # uniform over all attitudes (Haar measure on rotations)
        rotations = _rotation().random(n, random_state=rng)
        return np.degrees(rotations.as_euler("XYZ"))
    yaw = rng.uniform(-180.0, 180.0, n)
    if orientations == "restricted":  # a vehicle that cannot turn over: full yaw, limited roll and pitch
        tilt = rng.uniform(-max_tilt_deg, max_tilt_deg, (n, 2))
        return np.column_stack([tilt, yaw])
    if orientations == "yaw":  # level turns only
        return np.column_stack([np.zeros(n), np.zeros(n), yaw])
    if orientations == "flight":
        return _flight(n, max_tilt_deg, rng)
    raise OptionError(f"orientations={orientations!r} is not valid; choose one of: {', '.join(ORIENTATIONS)}")


def _flight(n: int, max_tilt_deg: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """A recording in time order of level flight with turns: straight legs and banked turns, light turbulence.

    Legs of 4 % of the recording each: straight, or a turn at a random rate (up to three full turns per
    leg) with the bank that a coordinated turn needs, up to ±``max_tilt_deg``; pitch wanders within a
    third of that; ±1° of turbulence on both. Roll, pitch and yaw in degrees, shape (n, 3).
    """
    legs = max(1, round(n / max(1, n // 25)))
    rate = np.where(rng.random(legs) < 0.3, 0.0, rng.uniform(-3.0, 3.0, legs) * 360.0 / (n / legs))  # °/sample
    per_sample = np.repeat(rate, int(np.ceil(n / legs)))[:n]
    yaw = np.cumsum(per_sample) + rng.uniform(-180.0, 180.0)
    bank = max_tilt_deg * per_sample / max(float(np.max(np.abs(rate))), 1e-12)
    pitch = np.cumsum(rng.normal(0.0, 0.2, n))
    pitch = (max_tilt_deg / 3.0) * np.tanh(pitch / max(float(np.max(np.abs(pitch))), 1e-12) * 2.0)
    turbulence = rng.normal(0.0, 1.0, (n, 2))
    roll = np.clip(bank + turbulence[:, 0], -max_tilt_deg, max_tilt_deg)
    pitch = np.clip(pitch + turbulence[:, 1], -max_tilt_deg, max_tilt_deg)
    return np.column_stack([roll, pitch, (yaw + 180.0) % 360.0 - 180.0])


def simulate(
    n: int,
    *,
    soft_iron: ArrayLike | None = None,
    hard_iron: ArrayLike | None = None,
    field_strength: float = 1.0,
    inclination_deg: float = 64.0,
    noise: float = 0.0,
    orientations: str | ArrayLike = "uniform",
    max_tilt_deg: float = 20.0,
    resolution: float | None = None,
    field_drift: float = 0.0,
    eddy_current: ArrayLike | None = None,
    sample_rate_hz: float = 10.0,
    seed: int | np.random.Generator | None = None,
) -> Simulation:
    """Simulate ``n`` magnetometer samples from eq. (1).

    Parameters
    ----------
    n : int
        Number of samples.
    soft_iron : array_like, shape (3, 3), optional
        W of eq. (1), dimensionless (identity by default). Must be invertible.
    hard_iron : array_like, shape (3,), optional
        V of eq. (1), in output units (zero by default).
    field_strength : float
        B, in output units.
    inclination_deg : float
        δ, the magnetic inclination, degrees.
    noise : float
        Standard deviation of the Gaussian noise added to each axis, output units.
    orientations : {"uniform", "restricted", "yaw"} or array_like, shape (n, 3)
        ``"uniform"``: all attitudes equally likely (a full tumble). ``"restricted"``: full yaw, roll
        and pitch uniform within ±``max_tilt_deg`` (a vehicle that cannot be turned over). ``"yaw"``:
        level turns only. ``"flight"``: a recording in time order of level flight with banked turns,
        roll and pitch within ±``max_tilt_deg`` (an aircraft, a car, a boat). Or explicit (roll, pitch,
        yaw) rows in degrees.
    max_tilt_deg : float
        Roll and pitch limit of ``"restricted"``, degrees.
    resolution : float, optional
        Quantisation step (e.g. 1 for raw integer counts).
    field_drift : float
        Relative amplitude of a slow change of the field strength along the recording (0.005: ±0.5 %,
        as a crustal anomaly or a vehicle's own slowly changing field): a real effect no calibration
        model holds. The truth keeps the nominal ``field_strength``.
    eddy_current : array_like, shape (3, 3), optional
        E of eq. (1e), seconds: the vehicle's eddy-current field, ``E ḃ``, where ``ḃ`` is the rate of change
        of the field in the sensor frame along the recording (samples ``1 / sample_rate_hz`` apart, in
        the order of ``orientations``). Model error that follows the manoeuvres; the truth leaves it out.
    sample_rate_hz : float
        The samples' rate, for ``eddy_current``.
    seed : int or numpy Generator, optional
        Seed of the random draws, for repeatable samples.
    """
    if n < 1:
        raise OptionError(f"n must be at least 1, got {n}")
    if noise < 0:
        raise OptionError(f"noise must be >= 0, got {noise}")
    if not field_strength > 0:
        raise OptionError(f"field_strength must be positive, got {field_strength}")
    rng = np.random.default_rng(seed)
    w = np.eye(3) if soft_iron is None else np.asarray(soft_iron, dtype=np.float64)
    v = np.zeros(3) if hard_iron is None else np.asarray(hard_iron, dtype=np.float64)
    if w.shape != (3, 3) or abs(np.linalg.det(w)) < 1e-12:
        raise OptionError("soft_iron must be an invertible 3x3 matrix")
    if v.shape != (3,):
        raise OptionError(f"hard_iron must have shape (3,), got {v.shape}")
    if not sample_rate_hz > 0:
        raise OptionError(f"sample_rate_hz must be positive, got {sample_rate_hz}")
    eddy = None if eddy_current is None else np.asarray(eddy_current, dtype=np.float64)
    if eddy is not None and eddy.shape != (3, 3):
        raise OptionError(f"eddy_current must be a 3x3 matrix (seconds), got shape {eddy.shape}")
    attitudes = _attitudes(n, orientations, max_tilt_deg, rng)
    clean = _model(attitudes, w, v, field_strength, inclination_deg)
    if eddy is not None and n > 1:  # E ḃ of eq. (1e): ḃ by central differences of b = W⁻¹ (B_p − V)
        field = (clean - v) @ np.linalg.inv(w).T
        clean = clean + np.gradient(field, 1.0 / sample_rate_hz, axis=0) @ eddy.T
    if field_drift:
        along = 1.0 + field_drift * np.cos(1.5 * np.pi * np.arange(n) / max(n - 1, 1))  # +drift to −drift
        clean = (clean - v) * along[:, None] + v  # W is linear: scaling the field scales W R B f
    samples = clean + rng.normal(0.0, noise, clean.shape) if noise > 0 else clean.copy()
    if resolution is not None:
        samples = np.round(samples / resolution) * resolution
    truth = Calibration("truth", v, np.asarray(np.linalg.inv(w), dtype=np.float64), field_strength)
    return Simulation(samples, clean, attitudes, truth, w, v, float(field_strength), float(inclination_deg))


# ---------------------------------------------------------------------- the paper's experiment

SENSORS = ("mpu9250", "ellipse2a")
DISTURBANCES = ("none", "steel", "smartphone")


def _axis_rotation(axis: tuple[float, float, float], degrees: float) -> NDArray[np.float64]:
    vector = np.asarray(axis, dtype=np.float64)
    return _rotation().from_rotvec(np.radians(degrees) * vector / np.linalg.norm(vector)).as_matrix()


@dataclass(frozen=True, eq=False)
class Scenario:
    """One cell of the paper's experiment: a sensor and a disturbance, with eq. (1)'s parameters.

    The ellipsoid semi-axes and hard-iron offsets are those of the paper's last two tables. The paper
    gives no axis directions; the soft iron is turned by a modest rotation (none for ``none``, 10° about
    z for ``smartphone``, 20° about (1, 1, 0) for ``steel``) so that min/max meets the misalignment real
    iron causes. The noise is the spread the paper measured after its best fit in the undisturbed case
    (std 0.0236 for the MPU-9250, 0.0108 for the Ellipse 2A, times the field strength).
    """

    sensor: str
    disturbance: str
    unit: str
    field_strength: float
    semi_axes: tuple[float, float, float]
    hard_iron: tuple[float, float, float]
    noise: float
    resolution: float | None
    axes_rotation: NDArray[np.float64] = field(repr=False)
    inclination_deg: float = 64.0

    @property
    def soft_iron(self) -> NDArray[np.float64]:
        """W = Q diag(semi_axes / B) Qᵀ: turns the sphere of radius B into the paper's ellipsoid."""
        q = self.axes_rotation
        return q @ np.diag(np.asarray(self.semi_axes) / self.field_strength) @ q.T

    @property
    def name(self) -> str:
        return f"{self.sensor}/{self.disturbance}"

    def simulate(
        self,
        n: int,
        *,
        seed: int | np.random.Generator | None = None,
        orientations: str | ArrayLike = "uniform",
        max_tilt_deg: float = 20.0,
        noise: float | None = None,
    ) -> Simulation:
        """Simulate ``n`` samples of this scenario (``noise`` overrides the sensor's)."""
        return simulate(
            n,
            soft_iron=self.soft_iron,
            hard_iron=self.hard_iron,
            field_strength=self.field_strength,
            inclination_deg=self.inclination_deg,
            noise=self.noise if noise is None else noise,
            orientations=orientations,
            max_tilt_deg=max_tilt_deg,
            resolution=self.resolution,
            seed=seed,
        )


# Paper, section V: semi-axes and hard-iron offsets of the soft + hard iron fit.
_PAPER_TABLE: dict[tuple[str, str], tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    ("mpu9250", "none"): ((262.0, 283.0, 272.0), (-91.5, 104.0, -274.0)),
    ("mpu9250", "steel"): ((193.0, 714.0, 1362.0), (-130.0, -177.0, -175.0)),
    ("mpu9250", "smartphone"): ((275.0, 299.0, 312.0), (-85.0, 172.0, -432.0)),
    ("ellipse2a", "none"): ((1.09, 1.02, 1.05), (0.008, -0.012, 0.048)),
    ("ellipse2a", "steel"): ((1.24, 0.55, 0.50), (0.11, 0.0037, 0.055)),
    ("ellipse2a", "smartphone"): ((0.93, 0.85, 0.86), (0.30, 0.24, 0.47)),
}
_SENSOR_MODEL = {  # unit, field strength B, noise std, quantisation step
    "mpu9250": ("counts", 270.0, 0.0236 * 270.0, 1.0),
    "ellipse2a": ("normalized", 1.0, 0.0108, None),
}
_ROTATIONS = {
    "none": ((0.0, 0.0, 1.0), 0.0),
    "smartphone": ((0.0, 0.0, 1.0), 10.0),
    "steel": ((1.0, 1.0, 0.0), 20.0),
}


def scenario(sensor: str, disturbance: str) -> Scenario:
    """The paper's scenario for ``sensor`` in ``SENSORS`` and ``disturbance`` in ``DISTURBANCES``."""
    if sensor not in SENSORS:
        raise OptionError(f"unknown sensor {sensor!r}; choose one of: {', '.join(SENSORS)}")
    if disturbance not in DISTURBANCES:
        raise OptionError(f"unknown disturbance {disturbance!r}; choose one of: {', '.join(DISTURBANCES)}")
    semi_axes, offset = _PAPER_TABLE[sensor, disturbance]
    unit, strength, noise, resolution = _SENSOR_MODEL[sensor]
    axis, angle = _ROTATIONS[disturbance]
    return Scenario(
        sensor=sensor,
        disturbance=disturbance,
        unit=unit,
        field_strength=strength,
        semi_axes=semi_axes,
        hard_iron=offset,
        noise=noise,
        resolution=resolution,
        axes_rotation=_axis_rotation(axis, angle),
    )
