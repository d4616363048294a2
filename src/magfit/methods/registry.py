"""The table of calibration methods behind :func:`magfit.fit`.

A method is a function ``f(data: FitInput, *, <options>) -> Calibration`` registered under a name with
:func:`register`. Its keyword-only parameters are its options: :func:`magfit.fit` rejects any other
name, listing the valid ones. ``data="statistics"`` methods read only the sufficient statistics (so they
also accept a :class:`~magfit.Statistics` built in chunks); ``data="samples"`` methods need the samples.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError

if TYPE_CHECKING:
    from ..calibration import Calibration
    from ..statistics import Statistics

__all__ = ["METHODS", "FitInput", "MethodSpec", "get_method", "register"]


@dataclass(frozen=True)
class FitInput:
    """What a method receives: the statistics always, the samples when the caller gave them.

    The samples are (N, 3) and finite, in the caller's dtype (float32 stays float32 for the methods that
    only read the statistics); :meth:`require_samples` gives them as float64 (no copy when they are).
    """

    statistics: Statistics
    samples: NDArray[Any] | None

    def require_samples(self, method: str) -> NDArray[np.float64]:
        if self.samples is None:
            raise OptionError(f"method {method!r} needs the samples themselves, not Statistics")
        return np.asarray(self.samples, dtype=np.float64)


@dataclass(frozen=True)
class MethodSpec:
    """A registered method: its function, the data it needs and its options."""

    name: str
    function: Callable[..., Calibration]
    min_samples: int
    data: Literal["statistics", "samples"]
    summary: str
    #: Checks run by :func:`magfit.fit` before the method, each ``check(statistics, method_name)``
    #: raising :class:`~magfit.CalibrationError` when the data cannot support this method.
    checks: tuple[Callable[[Statistics, str], None], ...] = ()
    #: Options the method cannot run without: inputs beyond the samples (``vector``'s reference field).
    #: Methods that run on samples alone (every magnitude-only fit) need none.
    needs: tuple[str, ...] = ()

    @property
    def options(self) -> tuple[str, ...]:
        """Names of the keyword-only options the method accepts."""
        return tuple(self.defaults)

    @property
    def defaults(self) -> dict[str, Any]:
        """The keyword-only options with their default values."""
        parameters = inspect.signature(self.function).parameters.values()
        return {p.name: p.default for p in parameters if p.kind is inspect.Parameter.KEYWORD_ONLY}


METHODS: dict[str, MethodSpec] = {}


def register(
    name: str,
    *,
    min_samples: int,
    data: Literal["statistics", "samples"],
    summary: str,
    checks: tuple[Callable[[Statistics, str], None], ...] = (),
    needs: tuple[str, ...] = (),
) -> Callable[[Callable[..., Calibration]], Callable[..., Calibration]]:
    """Decorator that adds a method to :data:`METHODS` under ``name``."""

    def decorate(function: Callable[..., Calibration]) -> Callable[..., Calibration]:
        if name in METHODS:
            raise RuntimeError(f"method {name!r} registered twice")
        METHODS[name] = MethodSpec(name, function, min_samples, data, summary, checks, needs)
        return function

    return decorate


def get_method(name: str) -> MethodSpec:
    """The method registered as ``name``, or an :class:`OptionError` that lists the valid names."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise OptionError(f"unknown method {name!r}; valid methods: {', '.join(METHODS)}") from None
