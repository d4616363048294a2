"""The motors' field as a calibration holds it: :class:`MotorTerm`.

Currents in a vehicle's power wires, ESCs and motors add a field to the compass's reading that is, to first
order, proportional to the current (or to the throttle, which drives it). magfit's model with that term
(docs/methods.md, "The motors' field", eq. M1)::

    raw(t) = W R(t) B e + V + k c(t − τ)          # k: (3,), in the raw samples' axes and unit per unit of c
    corrected = matrix @ (raw − offset − k c(t − τ))

``c`` is the regressor (the battery's current in amperes, or the throttle from 0 to 1), ``τ`` its lag (the
regressor taken ``τ`` seconds before the sample). ``k`` lives in the raw samples' axes, **before** the
soft-iron matrix, as PX4 applies ``CAL_MAGn_XCOMP`` (``raw + power·COMP − OFF``); ArduPilot adds its
``COMPASS_MOT`` after the matrix, and its export converts (``MOT = −D·SCALE·k``, docs/exports.md).

This module is plain data, below :mod:`magfit.calibration`, which holds one as ``Calibration.motor``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFileError, SampleError

__all__ = ["REGRESSORS", "REGRESSOR_UNITS", "MotorTerm"]

#: What drives the motors' field: the battery's current, or the throttle.
REGRESSORS = ("current", "throttle")
#: The unit of each regressor: amperes; the throttle as a fraction of full (0 to 1).
REGRESSOR_UNITS = {"current": "A", "throttle": "1"}


@dataclass(frozen=True, eq=False)
class MotorTerm:
    """The motors' field, ``k c(t − τ)``, removed from the raw samples before the offset and the matrix.

    Attributes
    ----------
    regressor : {"current", "throttle"}
        What ``c`` is.
    coefficients : ndarray, shape (3,)
        ``k``: the field per unit of the regressor, in the calibration's unit per ampere (current) or per
        full throttle (throttle), in the raw samples' axes (before the matrix).
    lag_s : float
        ``τ``: the regressor is taken ``lag_s`` seconds before each sample (negative: after).
    full_scale : float
        The largest regressor the recording held (amperes, or throttle): where the interference is
        reported ("% of the field at full current", as ArduPilot's compassmot reports it).
    """

    regressor: str
    coefficients: NDArray[np.float64]
    lag_s: float = 0.0
    full_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.regressor not in REGRESSORS:
            raise SampleError(f"MotorTerm.regressor must be one of {', '.join(REGRESSORS)}; got {self.regressor!r}")
        coefficients = np.array(self.coefficients, dtype=np.float64)
        if coefficients.shape != (3,) or not np.all(np.isfinite(coefficients)):
            raise SampleError(f"MotorTerm.coefficients must be 3 finite numbers, got {coefficients.tolist()}")
        coefficients.flags.writeable = False
        object.__setattr__(self, "coefficients", coefficients)
        for name in ("lag_s", "full_scale"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise SampleError(f"MotorTerm.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.full_scale <= 0:
            raise SampleError(f"MotorTerm.full_scale must be positive, got {self.full_scale}")

    @property
    def unit(self) -> str:
        """The regressor's unit: ``"A"`` or ``"1"`` (a fraction of full throttle)."""
        return REGRESSOR_UNITS[self.regressor]

    @property
    def frame(self) -> str:
        """Always ``"raw"``: the coefficients are in the raw samples' axes, applied before the matrix."""
        return "raw"

    def field(self, regressor: ArrayLike) -> NDArray[np.float64]:
        """``k c`` for each value of the regressor, shape (N, 3) (or (3,) for a scalar), the calibration's unit."""
        values = np.asarray(regressor, dtype=np.float64)
        if values.ndim > 1:
            raise SampleError(f"the regressor must be one value per sample, shape (N,), got shape {values.shape}")
        return np.multiply.outer(values, self.coefficients)

    def at_full_scale(self) -> float:
        """``|k| · full_scale``: the interference at the largest regressor, in the calibration's unit."""
        return float(np.linalg.norm(self.coefficients) * self.full_scale)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MotorTerm):
            return NotImplemented
        return (
            self.regressor == other.regressor
            and np.array_equal(self.coefficients, other.coefficients)
            and self.lag_s == other.lag_s
            and self.full_scale == other.full_scale
        )

    __hash__ = None  # type: ignore[assignment]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, lossless."""
        return {
            "regressor": self.regressor,
            "unit": self.unit,
            "frame": self.frame,
            "coefficients": self.coefficients.tolist(),
            "lag_s": self.lag_s,
            "full_scale": self.full_scale,
        }

    @classmethod
    def from_dict(cls, data: Any) -> MotorTerm:
        """Inverse of :meth:`to_dict`; anything else raises :class:`DataFileError` naming the field."""
        if not isinstance(data, Mapping):
            raise DataFileError(f"calibration 'motor' must be an object, got {type(data).__name__}")
        regressor = data.get("regressor")
        if regressor not in REGRESSORS:
            raise DataFileError(f"calibration 'motor.regressor' must be one of {', '.join(REGRESSORS)}")
        unit = REGRESSOR_UNITS[regressor]
        if data.get("frame", "raw") != "raw" or data.get("unit", unit) != unit:
            raise DataFileError("calibration 'motor' has a frame or unit this magfit does not know")
        values = data.get("coefficients")
        if not isinstance(values, list) or len(values) != 3:
            raise DataFileError("calibration 'motor.coefficients' must be a list of 3 numbers")
        numbers = []
        for name, value in [*(("coefficients", v) for v in values), ("lag_s", data.get("lag_s", 0.0)),
                            ("full_scale", data.get("full_scale", 1.0))]:  # fmt: skip
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
                raise DataFileError(f"calibration 'motor.{name}' must be a finite number, got {value!r:.40}")
            numbers.append(float(value))
        try:
            return cls(regressor, np.array(numbers[:3]), lag_s=numbers[3], full_scale=numbers[4])
        except SampleError as error:
            raise DataFileError(f"calibration 'motor' is not usable: {error}") from None
