"""Where the accelerometer sees gravity alone: the samples whose specific force is the vertical.

The accelerometer reads the specific force ``a = attitudeᵀ (acceleration − g)``: gravity's direction only while
the vehicle does not accelerate. Every method that takes the vertical from it (the alignment from gravity and
the inclination, :mod:`magfit.alignment`; the gravity equations of the ``vector`` and ``gyro`` fits) keeps the
samples this module lets through.

Which motions accelerate a vehicle. A vehicle moving at speed v whose velocity turns at the rate Ω accelerates
by ``v Ω`` across its track. It turns its track with its heading, so Ω is the heading's rate of turn: the
acceleration is then horizontal, tilts the apparent gravity by ``atan(v Ω / g)`` (0.75° at 25 m/s and
0.3°/s) and hides from |a| (a coordinated turn's entirely). A pitch-up at speed accelerates along the vertical:
|a| changes and the tolerance on |a| catches it. A rotation about a horizontal axis through the sensor
(rolling in waves, tilting by hand) accelerates nothing, and a sensor at a lever arm h from that axis only by
``α h`` (0.1 m/s², 0.5°, for a 15° roll every 6 s at 0.35 m). So the gates are:

- ``|a|`` within ``accel_tolerance`` of g (the median |a| of the samples the rate gates keep, when a gyroscope
  is given: a car that turns most of the time reads more than g on most samples);
- the heading's rate of turn (from the gyro, bias removed, and the accelerometer's tilt), averaged over about
  a second, at most ``max_rate_dps``: the track of a car, a boat or an aircraft turns with its heading;
- the whole rate at most ``max_tilt_rate_dps`` (the lever arm's share grows with it).

Not caught: a multirotor accelerating sideways without turning tilts its thrust, and its accelerometer reads
``g / cos(tilt)`` along its own z: within the |a| tolerance of 3 % that is up to 14° of tilt read as level.
Its still samples are the hover; the alignment's robust loss and its dip scatter are the only guards.

Without a gyroscope the heading's rate and the rest cannot be told apart: the rate at which the field and
gravity directions turn (the larger of the two, over two seconds) is held to ``max_rate_dps`` as a whole. It is
a weaker gate (the directions' own noise; what it kept on simulated cars: docs/methods.md, "Alignment without
attitude").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import SampleError

__all__ = ["ACCEL_TOLERANCE", "MAX_RATE_DPS", "MAX_TILT_RATE_DPS", "StillSamples", "moving_mean", "still_samples"]

#: Largest relative deviation of |a| from g for a sample to count as "the accelerometer sees gravity".
ACCEL_TOLERANCE = 0.03
#: Default largest turn rate about the vertical (°/s): at 25 m/s a 0.3°/s turn tilts gravity by 0.75°.
MAX_RATE_DPS = 0.3
#: Default largest rate about the horizontal axes (°/s): a boat's roll (±15° every 5-9 s peaks at 10-19°/s).
MAX_TILT_RATE_DPS = 30.0
#: Fewest steady samples from which the gyroscope's bias is taken.
_MIN_STEADY = 50


@dataclass(frozen=True)
class StillSamples:
    """The samples on which the accelerometer sees gravity alone (:func:`still_samples`).

    Attributes
    ----------
    keep : ndarray of bool, shape (N,)
    width : int
        Samples in about a second (1 when no rate was gated: then nothing may be averaged).
    dropped : dict
        Why the others were left out: reason → count (reasons with no sample left out are kept, count 0).
    notes : tuple of str
        What the reader should know (a gyroscope bias taken off, time stamps that look like milliseconds).
    """

    keep: NDArray[np.bool_]
    width: int
    dropped: dict[str, int]
    notes: tuple[str, ...]


def moving_mean(values: NDArray[np.float64], width: int) -> NDArray[np.float64]:
    """The mean over ``width`` samples centred on each (the ends padded with the edge value)."""
    if width <= 1:
        return values
    kernel = np.ones(width) / width
    padded = np.pad(values, (width // 2, width - 1 - width // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def _direction_rate(vectors: NDArray[np.float64], time_s: NDArray[np.float64], width: int) -> NDArray[np.float64]:
    """How fast (rad/s) the direction of ``vectors`` turns at each sample: the angle between the mean
    directions ``width`` samples apart (means over ``width`` samples: one sample's noise would read as tens
    of degrees per second at 50 Hz)."""
    unit = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    mean = np.column_stack([moving_mean(unit[:, i], width) for i in range(3)])
    n = len(unit)
    ahead = np.minimum(np.arange(n) + width // 2, n - 1)
    behind = np.maximum(np.arange(n) - width // 2, 0)
    dt = time_s[ahead] - time_s[behind]
    turned = np.linalg.norm(mean[ahead] - mean[behind], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(dt > 0, turned / dt, np.inf)


def _accel_reason(tolerance: float, *, slow: bool) -> str:
    where = " of the samples that turn slowly" if slow else ""
    return f"|a| more than {100 * tolerance:g} % away from g (the median |a|{where})"


def still_samples(
    accel: NDArray[np.float64],
    *,
    mag: NDArray[np.float64] | None = None,
    gyro: NDArray[np.float64] | None = None,
    time_s: NDArray[np.float64] | None = None,
    max_rate_dps: float | None = MAX_RATE_DPS,
    max_tilt_rate_dps: float = MAX_TILT_RATE_DPS,
    accel_tolerance: float = ACCEL_TOLERANCE,
) -> StillSamples:
    """The samples on which the accelerometer sees gravity alone (the gates in the module docstring).

    ``accel`` (N, 3) is the specific force in any unit; ``mag`` (the field, any frame) and ``time_s`` let the
    rate be measured without a gyroscope and the gyroscope's bias be taken off; ``gyro`` is in rad/s, in
    the accelerometer's axes. ``max_rate_dps=None`` gates |a| only (a rotation about the sensor itself).
    """
    notes: list[str] = []
    dropped: dict[str, int] = {}
    norm_a = np.linalg.norm(accel, axis=1)
    g = float(np.median(norm_a))
    if not g > 0:
        raise SampleError("the accelerometer reads zero on most samples: no gravity to take the vertical from")
    keep = np.abs(norm_a / g - 1.0) <= accel_tolerance
    dropped[_accel_reason(accel_tolerance, slow=False)] = int(np.sum(~keep))
    if max_rate_dps is None:
        return StillSamples(keep, 1, dropped, tuple(notes))
    if time_s is not None and time_s.size > 1:
        step = float(np.median(np.diff(time_s)))
        width = max(1, round(1.0 / step)) if step > 0 else 1
        if step >= 1.0:  # milliseconds given as seconds would let every turn through the gate
            notes.append(f"the samples are {step:g} s apart: if time_s is not in seconds, the rate gate is wrong")
    else:
        width = 5
    turning = None
    if time_s is not None:
        # The field direction misses a rotation about the field, gravity's one about gravity: the larger
        # sees every turn (a level yaw turn moves the field direction at ω cos δ). Over two seconds, so that
        # the accelerometer's noise stays below the gate.
        turning = _direction_rate(accel, time_s, 2 * width)
        if mag is not None:
            turning = np.maximum(turning, _direction_rate(mag, time_s, 2 * width))
    limit = math.radians(max_rate_dps)
    if gyro is None:
        if turning is None:
            notes.append(
                "no gyroscope and no time stamps: samples taken while turning cannot be recognised, their "
                "centripetal accelerations are only down-weighted as outliers"
            )
            return StillSamples(keep, 1, dropped, tuple(notes))
        still = moving_mean(turning, width) <= limit
        if np.sum(still) >= _MIN_STEADY:  # g from the slow samples, as with a gyroscope below
            g = float(np.median(norm_a[still]))
            keep = np.abs(norm_a / g - 1.0) <= accel_tolerance
            dropped = {_accel_reason(accel_tolerance, slow=True): int(np.sum(~keep))}
        dropped[f"turning faster than {max_rate_dps:g}°/s (from the turning of the field and gravity directions)"] = (
            int(np.sum(keep & ~still))
        )
        return StillSamples(keep & still, width, dropped, tuple(notes))

    rates = gyro
    if turning is not None:
        # An uncalibrated gyroscope's bias (tenths of a degree per second, above the gate) reads as turning on
        # every sample: its median on the samples whose field and gravity directions hold still (which no bias
        # reaches) is taken as the bias. Without time stamps there are no such samples: none is taken.
        steady = moving_mean(turning, width) <= limit
        if np.sum(steady) >= _MIN_STEADY:
            bias = np.median(gyro[steady], axis=0)
            rates = gyro - bias
            if np.degrees(np.linalg.norm(bias)) > 0.05:
                notes.append(
                    "the gyroscope's bias, its median rate where the field and gravity directions hold still: "
                    "({:+.2f}, {:+.2f}, {:+.2f})°/s, taken off".format(*np.degrees(bias))
                )
    down = -accel / np.where(norm_a > 0, norm_a, 1.0)[:, None]
    down = np.column_stack([moving_mean(down[:, i], width) for i in range(3)])
    down /= np.maximum(np.linalg.norm(down, axis=1, keepdims=True), 1e-12)
    # The track turns with the heading: the azimuth of a body axis e that stays near the horizontal (forward,
    # or sideways), whose rate is (ω·d − (ω·e)(e·d)) / (1 − (e·d)²) (for e = x: the Euler kinematics'
    # ψ' = (q d_y + r d_z) / (d_y² + d_z²)). Not ω·d: a boat rolling while it pitches turns about a tilted roll
    # axis, which has a vertical part (1.2°/s at 19°/s of roll and 3.7° of pitch) but leaves its heading alone.
    # e is the axis that tilts least over the recording: an IMU mounted sideways or on end has its own.
    axis = int(np.argmin(np.mean(down**2, axis=0)))
    along = down[:, axis]
    level = 1.0 - along**2
    with np.errstate(divide="ignore", invalid="ignore"):
        heading_rate = np.where(
            level > 0.25,  # e pitched beyond 60°: its azimuth is ill-defined; the whole rate counts
            (np.einsum("ij,ij->i", rates, down) - rates[:, axis] * along) / level,
            np.linalg.norm(rates, axis=1),
        )
    # Averaged over about a second: the gyro's noise averages out, turn edges widen.
    turn = moving_mean(np.abs(heading_rate), width) <= limit
    tilt = moving_mean(np.linalg.norm(rates, axis=1), width) <= math.radians(max_tilt_rate_dps)
    if np.sum(turn & tilt) >= _MIN_STEADY:
        # g from the samples that neither turn nor tilt fast: a car that turns most of the time reads
        # √(g² + (vΩ)²) on most samples, and their median would leave its straight stretches out.
        g = float(np.median(norm_a[turn & tilt]))
        keep = np.abs(norm_a / g - 1.0) <= accel_tolerance
        dropped = {_accel_reason(accel_tolerance, slow=True): int(np.sum(~keep))}
    dropped[f"turning faster than {max_rate_dps:g}°/s in heading (from the gyroscope)"] = int(np.sum(keep & ~turn))
    dropped[f"rotating faster than {max_tilt_rate_dps:g}°/s (from the gyroscope)"] = int(np.sum(keep & turn & ~tilt))
    return StillSamples(keep & turn & tilt, width, dropped, tuple(notes))
