"""The offset's drift with temperature, where a log has the magnetometer's temperature (PX4 ``sensor_mag``).

A magnetometer's offset moves as it warms (the chip's own bias, and the hard iron of a board heating up).
With the calibration ``c = M (x − V)`` fitted on the whole log and a drift ``d`` per °C about the log's mean
temperature ``T̄``, each sample obeys ``|M (x_k − V − δV − d τ_k)| = B + δB`` with ``τ_k = T_k − T̄``. To first
order, with ``u_k = M (x_k − V)`` and ``n_k = u_k / |u_k|``::

    |u_k| − B = (Mᵀ n_k)ᵀ δV + τ_k (Mᵀ n_k)ᵀ d + δB                                          (T1)

a linear least-squares problem in ``(δV, d, δB)``: ``δV`` and ``δB`` take up what the whole-log fit already
absorbed. The whole-log fit's matrix may have absorbed part of the drift too, so a symmetric change ``δS`` of
it is fitted with them (``|(I + δS) u_k| ≈ |u_k| + n_kᵀ δS u_k``; five more columns, the trace being δB)::

    |u_k| − B = (Mᵀ n_k)ᵀ δV + τ_k (Mᵀ n_k)ᵀ d + δB + n_kᵀ δS u_k                            (T2)
 ``d`` is the offset's change per °C per axis, in the sensor's axes and unit (the firmware's offset
grows by ``d`` per °C: the samples must be corrected with ``V + d (T − T̄)``). Its one-sigma is a block
jackknife over 20 contiguous stretches, or the least-squares covariance with the residuals' correlation in time
(batch means over the same stretches), whichever is larger (the samples are correlated in time, and a log warms
up slowly).

It is determined when the temperature varies (a standard deviation of 1 °C at least) and the directions the
field took while it varied let (T1) separate ``d`` from ``δV`` (the smallest singular value of the centred
design, relative to the largest, at least 0.05); otherwise it is refused with the reason (code
``undetermined``). Over a few degrees a straight line is all the data determine: where it is determined,
PX4's ``TC_Mn_*`` thermal compensation is exported as that line (:mod:`magfit.export.px4_temperature`: the
cubic's higher coefficients zero, the temperature clipped to the log's range), and refused with the reason
where it is not.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples
from .calibration import Calibration
from .errors import DataFileError, SampleError
from .findings import Reason, ReasonList

if TYPE_CHECKING:
    from .pipeline import FileCalibration

__all__ = ["TemperatureDrift", "compass_drift", "log_drifts", "offset_drift", "read_mag_temperature"]

_PAIRS = ((0, 1), (0, 2), (1, 2))
#: Below this standard deviation of the temperature (°C) no drift is determined.
MIN_TEMPERATURE_SPREAD = 1.0


@dataclass(frozen=True, eq=False)
class TemperatureDrift:
    """The offset's drift with temperature.

    Attributes
    ----------
    drift : ndarray, shape (3,)
        ``d``: the offset's change per °C per sensor axis, in ``unit``/°C (NaN when not determined).
    sigma : ndarray, shape (3,)
        Its block-jackknife one-sigma per axis.
    reference_c : float
        ``T̄``, the mean temperature, °C.
    range_c : (float, float)
        The lowest and highest temperature, °C.
    spread_c : float
        The temperature's standard deviation, °C.
    unit : str
        The samples' unit.
    determined : bool
        The data determine ``d`` (module docstring).
    reasons : tuple of Reason
        Why not, when not (code ``undetermined``).
    """

    drift: NDArray[np.float64]
    sigma: NDArray[np.float64]
    reference_c: float
    range_c: tuple[float, float]
    spread_c: float
    unit: str
    determined: bool
    reasons: tuple[Reason, ...] = ()


def _solve(design: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    return np.asarray(solution, dtype=np.float64)


def offset_drift(samples: ArrayLike, temperature_c: ArrayLike, calibration: Calibration) -> TemperatureDrift:
    """Fit the offset's drift per °C, eq. (T1), on ``samples`` (N, 3, raw, in time order) with their
    ``temperature_c`` (N,) and the whole log's ``calibration``.

    Raises
    ------
    SampleError
        The shapes disagree, or a temperature is not finite.
    """
    x = as_samples(samples)
    t = np.asarray(temperature_c, dtype=np.float64).reshape(-1)
    if len(t) != len(x):
        raise SampleError(f"offset_drift: {len(x)} samples but {len(t)} temperatures")
    if not np.all(np.isfinite(t)):
        raise SampleError("offset_drift: a temperature is NaN or infinite; drop those samples first")
    unit = calibration.unit or ""
    reference, spread = float(np.mean(t)), float(np.std(t))
    nan = np.full(3, np.nan)
    reasons = ReasonList()
    if spread < MIN_TEMPERATURE_SPREAD or len(x) < 40:
        reasons.add(
            "undetermined",
            f"the temperature hardly varies (standard deviation {spread:.2f} °C, {t.min():.1f} to {t.max():.1f} °C): "
            "no drift with temperature can be told from it; log a warm-up from cold",
        )
        return TemperatureDrift(
            nan, nan, reference, (float(t.min()), float(t.max())), spread, unit, False, tuple(reasons)
        )
    matrix = np.asarray(calibration.matrix, dtype=np.float64)
    u = (x - calibration.offset) @ matrix.T
    length = np.linalg.norm(u, axis=1)
    gradient = (u / length[:, None]) @ matrix  # (Mᵀ n_k)ᵀ as rows
    tau = t - reference
    n = u / length[:, None]
    # δS without its trace: an isotropic scale is δB again (n·u = |u|)
    shape = [n[:, i] * u[:, i] - n[:, 2] * u[:, 2] for i in range(2)]
    shape += [n[:, i] * u[:, j] + n[:, j] * u[:, i] for i, j in _PAIRS]
    # (δV, d, δB, δS), eq. (T1) with the soft iron free to re-adjust too (T2)
    design = np.column_stack([gradient, tau[:, None] * gradient, np.ones(len(x)), *shape])
    target = length - float(calibration.field_strength)
    scaled = design / np.maximum(np.linalg.norm(design, axis=0), 1e-300)
    singular = np.linalg.svd(scaled, compute_uv=False)
    conditioned = singular[-1] / singular[0] >= 0.05
    drift = _solve(design, target)[3:6]
    blocks = 20
    edges = np.linspace(0, len(x), blocks + 1).astype(int)
    estimates = []
    for lo, hi in itertools.pairwise(edges):
        keep = np.ones(len(x), dtype=bool)
        keep[lo:hi] = False
        estimates.append(_solve(design[keep], target[keep])[3:6])
    spread_d = np.asarray(estimates) - np.mean(estimates, axis=0)
    jackknife = np.sqrt((blocks - 1) / blocks * np.sum(spread_d**2, axis=0))
    # The least-squares covariance with the residuals' correlation in time (batch means): the larger is stated.
    residual = target - design @ _solve(design, target)
    size = len(x) // blocks
    means = residual[: size * blocks].reshape(blocks, size).mean(axis=1)
    inflation = max(1.0, size * float(np.var(means)) / max(float(np.var(residual)), 1e-300))
    dof = max(len(x) - design.shape[1], 1)
    covariance = inflation * float(residual @ residual) / dof * np.linalg.pinv(design.T @ design)
    sigma = np.maximum(jackknife, np.sqrt(np.diag(covariance)[3:6]))
    if not conditioned:
        reasons.add(
            "undetermined",
            "the field's directions while the temperature changed do not separate a drift from the offset itself "
            f"(relative singular value {singular[-1] / singular[0]:.3f} < 0.05): turn the vehicle while it warms up",
        )
        return TemperatureDrift(
            nan, nan, reference, (float(t.min()), float(t.max())), spread, unit, False, tuple(reasons)
        )
    return TemperatureDrift(drift, sigma, reference, (float(t.min()), float(t.max())), spread, unit, True, ())


def read_mag_temperature(path: str | Path, sensor: str) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The temperature (°C) a PX4 ULog's ``sensor_mag`` instance logged, with its time stamps (s): ``sensor`` is
    ``sensor_mag/N``. None when the log or the topic has no ``temperature`` field (NaN values dropped).

    Raises
    ------
    DataFileError
        The ULog cannot be read, or pyulog (the ``ulog`` extra) is missing.
    """
    topic, _, instance = sensor.partition("/")
    if topic != "sensor_mag" or not instance.isdigit():
        return None
    try:
        import pyulog
    except ImportError:
        raise DataFileError(f"{path}: reading a ULog needs pyulog: pip install 'magfit[ulog]'") from None
    try:
        log = pyulog.ULog(str(path), ["sensor_mag"])
    except Exception as error:  # pyulog raises bare exceptions on damaged files
        raise DataFileError(f"{path}: the ULog cannot be read ({error}); download it again") from None
    for data in log.data_list:
        if data.name == "sensor_mag" and data.multi_id == int(instance) and "temperature" in data.data:
            temperature = np.asarray(data.data["temperature"], dtype=np.float64)
            time_s = np.asarray(data.data["timestamp"], dtype=np.float64) / 1e6
            good = np.isfinite(temperature)
            return (time_s[good], temperature[good]) if np.any(good) else None
    return None


def log_drifts(result: FileCalibration) -> dict[str, TemperatureDrift]:
    """:func:`offset_drift` for each compass :func:`magfit.calibrate_file` fitted in a PX4 ULog whose
    ``sensor_mag`` logs its temperature (interpolated onto the samples' stamps); compasses without one are left out.

    Raises
    ------
    DataFileError
        The log cannot be read again.
    """
    drifts = {}
    for compass in result.compasses:
        if compass.sensor is None:
            continue
        drift = compass_drift(result.path, compass.sensor, compass.calibration)
        if drift is not None:
            drifts[compass.sensor] = drift
    return drifts


def compass_drift(path: str | Path, sensor: str, calibration: Calibration) -> TemperatureDrift | None:
    """:func:`offset_drift` of one compass of a PX4 ULog (``sensor_mag/N``) with the calibration fitted on it;
    None when the file is no ULog or that ``sensor_mag`` logs no temperature.

    Raises
    ------
    DataFileError
        The log cannot be read again.
    """
    from .sources import log_kind, open_source

    if log_kind(path) != "ulog":
        return None
    read = read_mag_temperature(path, sensor)
    if read is None or len(read[0]) < 2:
        return None
    samples = open_source(path).read(sensor)
    inside = (samples.time_s >= read[0][0]) & (samples.time_s <= read[0][-1])
    temperature = np.interp(samples.time_s[inside], *read)
    return offset_drift(samples.samples[inside], temperature, calibration)
