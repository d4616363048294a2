"""The other units a column of time stamps may be in: milliseconds or microseconds where its steps are long
enough to be (:func:`time_readings`).

A method that relates the samples' change to a rate (``gyro``: the field turns by ``ω dt``; ``vector``: the
reference turns as ``ṙ = r × ω``) sees time stamps in milliseconds as a rate 1000 times too slow, which a gyro
in degrees per second (57.3 times too fast) partly mimics: each candidate reading of the time is scored with
the gyro's, and the one that fits names its own column (reason code ``time_unit``, not ``gyro_unit``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["MS_STEP", "TimeReading", "time_readings"]

#: The median time step (in the column's units) from which the column may be in milliseconds: a rate-aided fit
#: logged at under 5 Hz is none; from 1000 times it, microseconds.
MS_STEP = 0.2


@dataclass(frozen=True)
class TimeReading:
    """The time stamps read in another unit: seconds are ``time * factor``; ``unit`` in words, ``divisor`` the
    figure to divide the column by (``"1000"``)."""

    factor: float
    unit: str
    divisor: str

    def words(self, name: str, step: float) -> str:
        """The clause that names the column: ``time_s= looks like milliseconds ...``."""
        return (
            f"{name} looks like {self.unit}: its steps are a median {step:.3g} units apart; give it in seconds "
            f"({name.rstrip('=')} / {self.divisor})"
        )


def time_readings(time_s: NDArray[np.float64]) -> list[TimeReading]:
    """The readings of ``time_s`` (strictly increasing) as milliseconds or microseconds that its median step
    allows (:data:`MS_STEP`)."""
    if time_s.size < 2:
        return []
    step = float(np.median(np.diff(time_s)))
    return [
        TimeReading(factor, unit, f"{1 / factor:.0f}")
        for factor, unit, minimum in ((1e-3, "milliseconds", MS_STEP), (1e-6, "microseconds", 1e3 * MS_STEP))
        if step >= minimum
    ]
