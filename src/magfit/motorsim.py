"""A simulated multirotor flight whose compass sees the motors' field: :func:`simulate_motor_flight`.

Hover with yaw turns and tilts (to ``max_tilt_deg``), the throttle following the climbs and the tilts, the
battery's current following the throttle (``current = idle + span · throttle^1.5``) with the ESCs' lag, and the
compass (eq. M1 of docs/methods.md)::

    raw = W (R(t)ᵀ B_ned) + V + k c(t − lag) + noise

in milligauss, W symmetric (so that the symmetric root magfit returns is the truth itself). ``k`` is in the
raw axes, per ampere (``driver="current"``) or per unit throttle (``driver="throttle"``); ``driver="none"``
is a clean vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .calibration import Calibration
from .motorterm import MotorTerm

__all__ = ["MotorFlight", "heading_error_deg", "simulate_motor_flight"]


@dataclass(frozen=True)
class MotorFlight:
    """The simulated flight: what a log would hold, and the truth."""

    time_s: NDArray[np.float64]
    samples: NDArray[np.float64]  # (N, 3) mG, raw
    current: NDArray[np.float64]  # (N,) A, at the compass's stamps (no lag: the logged current)
    throttle: NDArray[np.float64]  # (N,) 0-1
    attitude: NDArray[np.float64]  # (N, 3, 3) body -> NED
    field_ned: NDArray[np.float64]  # (3,) mG
    truth: Calibration  # with the true motor term (None on a clean vehicle)
    lag_s: float
    euler: NDArray[np.float64]  # (N, 3) roll, pitch, yaw in radians (Rz(yaw) Ry(pitch) Rx(roll), body -> NED)


def _rotation(roll: NDArray[np.float64], pitch: NDArray[np.float64], yaw: NDArray[np.float64]) -> NDArray[np.float64]:
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_matrix())


def simulate_motor_flight(
    duration_s: float = 300.0,
    rate_hz: float = 50.0,
    *,
    driver: str = "current",
    per_unit: float = 4.0,
    lag_s: float = 0.03,
    max_tilt_deg: float = 30.0,
    noise: float = 2.0,
    seed: int = 0,
    field_ned: NDArray[np.float64] | None = None,
) -> MotorFlight:
    """A hover of ``duration_s`` with turns and tilts; ``per_unit``: |k| in mG per A (or per full throttle);
    ``field_ned``: the Earth's field (mG, NED), else a random one."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz

    # Slow random attitude: several full yaw turns, tilts in every direction, throttle bursts.
    def smooth(scale: float, period_s: float) -> NDArray[np.float64]:
        knots = np.arange(0, duration_s + period_s, period_s)
        return np.interp(t, knots, rng.normal(0, scale, len(knots)))

    yaw = np.cumsum(smooth(0.6, 8.0)) / rate_hz + rng.uniform(0, 2 * np.pi)
    tilt = np.radians(max_tilt_deg)
    roll = np.clip(smooth(tilt / 2, 3.0), -tilt, tilt)
    pitch = np.clip(smooth(tilt / 2, 3.5), -tilt, tilt)
    lean = np.hypot(roll, pitch) / tilt
    throttle = np.clip(0.35 + 0.25 * lean + smooth(0.18, 2.0), 0.05, 1.0)
    current = 3.0 + 50.0 * throttle**1.5
    attitude = _rotation(roll, pitch, yaw)
    inclination = np.radians(rng.uniform(40, 65))
    strength = rng.uniform(400, 550)
    declination = rng.uniform(-0.3, 0.3)
    if field_ned is None:
        field_ned = strength * np.array(
            [np.cos(inclination) * np.cos(declination), np.cos(inclination) * np.sin(declination), np.sin(inclination)]
        )
    else:
        field_ned = np.asarray(field_ned, dtype=np.float64)
        strength = float(np.linalg.norm(field_ned))
    body = np.einsum("nji,j->ni", attitude, field_ned)
    a = rng.normal(0, 0.06, (3, 3))
    soft = np.eye(3) + (a + a.T) / 2
    offset = rng.uniform(-150, 150, 3)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    lagged_current = np.interp(t - lag_s, t, current)
    lagged_throttle = np.interp(t - lag_s, t, throttle)
    samples = body @ soft.T + offset + rng.normal(0, noise, (n, 3))
    motor = None
    if driver == "current":
        motor = MotorTerm("current", per_unit * direction, lag_s=lag_s, full_scale=float(current.max()))
        samples = samples + motor.field(lagged_current)
    elif driver == "throttle":
        motor = MotorTerm("throttle", per_unit * direction, lag_s=lag_s, full_scale=1.0)
        samples = samples + motor.field(lagged_throttle)
    elif driver != "none":
        raise ValueError(f"driver must be current, throttle or none; got {driver!r}")
    correction = np.linalg.inv(soft)
    scale = abs(np.linalg.det(correction)) ** (1 / 3)
    truth = Calibration("truth", offset, correction / scale, strength / scale, unit="mG", n_samples=n, motor=motor)
    return MotorFlight(
        t, samples, current, throttle, attitude, field_ned, truth, lag_s, np.column_stack([roll, pitch, yaw])
    )


def heading_error_deg(
    corrected: NDArray[np.float64], attitude: NDArray[np.float64], field_ned: NDArray[np.float64]
) -> float:
    """RMS tilt-compensated heading error (degrees): the corrected body-frame field turned level by the true
    roll and pitch, its heading against the true field's, with the fitted field's mean rotation about the
    vertical removed (a declination-like constant the magnitude cannot see is not a heading error here)."""
    ned = np.einsum("nij,nj->ni", attitude, corrected)
    heading = np.arctan2(ned[:, 1], ned[:, 0])
    truth = np.arctan2(field_ned[1], field_ned[0])
    error = np.angle(np.exp(1j * (heading - truth)))
    error = error - np.angle(np.mean(np.exp(1j * error)))
    return float(np.degrees(np.sqrt(np.mean(error**2))))
