"""The table of calibration methods behind :func:`magfit.fit`.

A method is a function ``f(data: FitInput, *, <options>) -> Calibration`` registered under a name with
:func:`register`. Its keyword-only parameters are its options: :func:`magfit.fit` rejects any other
name, listing the valid ones. ``data="statistics"`` methods read only the sufficient statistics (so they
also accept a :class:`~magfit.Statistics` built in chunks); ``data="samples"`` methods need the samples.

What a method adds to its verdict travels in its entry too (:class:`Judging`): its own refit for the
diagnostics, a quick stand-in for the repeated refits, a model error to add to the heading one-sigma and
weaknesses of its own. :func:`magfit.fit` reads them from the entry and names no method.

The built-in methods are known by name before their modules run (:data:`BUILT_IN`): :data:`METHODS` lists
them at once and imports a method's module the first time its entry is read, so that a command fitting a
recording with ``auto`` does not pay for ``gyro``'s or ``vector``'s imports.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, OptionError

if TYPE_CHECKING:
    from ..calibration import Calibration
    from ..facts import ModelKind
    from ..findings import Diagnostics, Reason
    from ..saturation import Clipping
    from ..statistics import Statistics

__all__ = [
    "BUILT_IN",
    "METHODS",
    "FitInput",
    "Judging",
    "MethodRegistry",
    "MethodSpec",
    "Undetermined",
    "fit_input",
    "get_method",
    "register",
]

#: A function that fits a method (with fixed options) to (n, 3) samples: what the diagnostics receive.
Refit = Callable[[NDArray[np.float64]], "Calibration"]
#: Given the calibration and the options it ran with, the refit the diagnostics use.
RefitFactory = Callable[["Calibration", Mapping[str, Any]], Refit]


class Undetermined(CalibrationError):
    """A method's refusal that carries the calibration a forced fit returns (``allow_undetermined=True``).

    ``calibration`` is the method's best answer all the same (``auto``: the model its unforced choice ranks
    best); :func:`magfit.fit` judges it, with this refusal first among its warnings.
    """

    def __init__(self, message: str, calibration: Calibration, code: str = "model_inadequate") -> None:
        super().__init__(message, codes=(code,))
        self.calibration = calibration


@dataclass(frozen=True)
class Judging:
    """What a method adds to the verdict :func:`magfit.fit` reaches on its calibration. Every field optional.

    Attributes
    ----------
    refit : callable or None
        ``refit(calibration, options) -> Refit``: how the diagnostics refit a calibration of this method
        (held-out folds, halves). None: the method itself with the options it ran with.
    stand_in : callable or None
        ``stand_in(calibration, options) -> Refit``: a quick fit that stands in for an iterative method in the
        refits repeated 10 times (the halves, the block jackknife): the same stretches of the recording move
        it the same way. None: the refit itself.
    model_error_deg : callable or None
        ``model_error_deg(calibration) -> float``: a heading error (degrees) the method knows its model may
        make, added to the heading one-sigma before the verdict.
    model_error_offset : callable or None
        ``model_error_offset(calibration) -> (3,) or None``: the offset error (input units, per axis) the same
        model error may cause, added to the offset one-sigma.
    weaknesses : callable or None
        ``weaknesses(calibration, report) -> tuple of Reason``: weaknesses the method names from its own facts.
    compare_ml : bool
        Whether the diagnostics compare the calibration with the maximum-likelihood fit of its model (moot for
        a method that returns that fit).
    """

    refit: RefitFactory | None = None
    stand_in: RefitFactory | None = None
    model_error_deg: Callable[[Calibration], float] | None = None
    model_error_offset: Callable[[Calibration], tuple[float, float, float] | None] | None = None
    weaknesses: Callable[[Calibration, Diagnostics], tuple[Reason, ...]] | None = None
    compare_ml: bool = True


@dataclass(frozen=True)
class FitInput:
    """What a method receives: the statistics always, the samples when the caller gave them.

    The samples are (N, 3) and finite, in the caller's dtype (float32 stays float32 for the methods that
    only read the statistics); :meth:`require_samples` gives them as float64 (no copy when they are).
    """

    statistics: Statistics
    samples: NDArray[Any] | None
    #: The rows of ``samples`` clipped at full scale, when the statistics' pass found them (None: not searched).
    clipping: Clipping | None = None

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
    #: The model family the method fits (:data:`magfit.facts.MODEL_KINDS`), recorded on its calibration by
    #: :func:`magfit.methods.core.estimate`; None: the method sets it itself (it depends on its options).
    model: ModelKind | None = None
    #: What the method adds to its verdict.
    judging: Judging = Judging()
    #: The most samples the method's fit reads of those it is given (a regular stride beyond), None: all of them.
    #: A file streamed to a subsample is subsampled to no more by default: more rows would not enter the fit,
    #: only the uncertainty stated for it (as if they had).
    fit_rows: int | None = None

    @property
    def options(self) -> tuple[str, ...]:
        """Names of the keyword-only options the method accepts."""
        return tuple(self.defaults)

    @property
    def defaults(self) -> dict[str, Any]:
        """The keyword-only options with their default values."""
        parameters = inspect.signature(self.function).parameters.values()
        return {p.name: p.default for p in parameters if p.kind is inspect.Parameter.KEYWORD_ONLY}


#: The built-in methods, in the order they are listed (``magfit.METHODS``, ``--help``, error messages): each
#: name and the module (below :mod:`magfit.methods`) whose :func:`register` adds it. To add a built-in
#: method, add its module and a line here.
BUILT_IN: dict[str, str] = {
    "als": "als",
    "robust": "robust",
    "auto": "auto",
    "diag": "diag",
    "ellipsoid": "ellipsoid",
    "gyro": "gyro.method",
    "minmax": "minmax",
    "ml": "ml",
    "sphere": "sphere",
    "tilt": "vector.tilt",
    "vector": "vector.method",
}


class MethodRegistry(MutableMapping[str, MethodSpec]):
    """The methods by name: the built-in ones known before their modules are imported, each imported the
    first time its entry is read (``METHODS[name]``, :func:`get_method`, ``.values()``).

    Listing the names (``list(METHODS)``, ``name in METHODS``, ``len``) imports nothing. A method registered
    at run time (:func:`register`, or ``METHODS[name] = spec``) joins the end of the list.
    """

    def __init__(self, modules: Mapping[str, str]) -> None:
        self._modules = {name: f"{__package__}.{module}" for name, module in modules.items()}
        self._specs: dict[str, MethodSpec] = {}
        self._names = list(modules)

    def module(self, name: str) -> str | None:
        """The module that registers the built-in method ``name`` (None for another method)."""
        return self._modules.get(name)

    def is_loaded(self, name: str) -> bool:
        """Whether the entry of ``name`` exists yet (its module imported)."""
        return name in self._specs

    def __getitem__(self, name: str) -> MethodSpec:
        spec = self._specs.get(name)
        if spec is not None:
            return spec
        module = self._modules.get(name)
        if module is None:
            raise KeyError(name)
        importlib.import_module(module)
        spec = self._specs.get(name)
        if spec is None:
            raise RuntimeError(f"module {module} did not register the method {name!r}")
        return spec

    def __setitem__(self, name: str, spec: MethodSpec) -> None:
        self._specs[name] = spec
        if name not in self._names:
            self._names.append(name)

    def __delitem__(self, name: str) -> None:
        if name not in self._names:
            raise KeyError(name)
        self._names.remove(name)
        self._specs.pop(name, None)
        self._modules.pop(name, None)

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._names))

    def __len__(self) -> int:
        return len(self._names)

    def __repr__(self) -> str:
        return f"MethodRegistry({', '.join(self._names)})"


METHODS = MethodRegistry(BUILT_IN)


def register(
    name: str,
    *,
    min_samples: int,
    data: Literal["statistics", "samples"],
    summary: str,
    checks: tuple[Callable[[Statistics, str], None], ...] = (),
    needs: tuple[str, ...] = (),
    model: ModelKind | None = None,
    judging: Judging | None = None,
    fit_rows: int | None = None,
) -> Callable[[Callable[..., Calibration]], Callable[..., Calibration]]:
    """Decorator that adds a method to :data:`METHODS` under ``name`` (see :class:`MethodSpec`)."""

    def decorate(function: Callable[..., Calibration]) -> Callable[..., Calibration]:
        owner = METHODS.module(name)
        if METHODS.is_loaded(name) or (owner is None and name in METHODS) or owner not in (None, function.__module__):
            raise RuntimeError(f"method {name!r} registered twice")
        METHODS[name] = MethodSpec(
            name, function, min_samples, data, summary, checks, needs, model, judging or Judging(), fit_rows
        )
        return function

    return decorate


def fit_input(data: object, method: str) -> FitInput:
    """``data`` when it is what :func:`magfit.fit` hands a method; a method function called directly with an
    array is refused in one line that names the call to make instead."""
    if not isinstance(data, FitInput):
        raise OptionError(
            f"the {method} method is run by magfit.fit(samples, method={method!r}, ...), which validates the samples "
            f"and judges the fit; its function takes the prepared input, not {type(data).__name__}"
        )
    return data


def get_method(name: str) -> MethodSpec:
    """The method registered as ``name``, or an :class:`OptionError` that lists the valid names."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise OptionError(f"unknown method {name!r}; valid methods: {', '.join(METHODS)}") from None
