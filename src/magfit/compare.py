"""Run several calibration methods on the same samples and score each one as the paper does (section V).

The paper compares its three methods by the signed distance of every calibrated sample to the unit
sphere, ``|matrix @ (raw − offset)| / field_strength − 1``, and reports its mean and standard deviation
(:func:`magfit.evaluate`). :func:`compare` runs that comparison for any list of methods: a method that
cannot fit the data (a :class:`~magfit.CalibrationError`) does not stop the others, its reason is kept.

:func:`evaluate_chunks` computes the same metric over a stream of chunks, for files too large to load.

Caveat (the paper's own setup): the metric is measured on the samples the methods were fitted to, so a
method with more parameters never looks worse on it; judge accuracy against a ground truth as well.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples
from .calibration import Calibration
from .errors import CalibrationError, OptionError, SampleError
from .evaluate import Evaluation, evaluate, sphere_distances
from .fit import fit
from .methods import get_method
from .remedy import audience, command_line

__all__ = ["PAPER_METHODS", "Comparison", "MethodResult", "compare", "evaluate_chunks"]

#: The paper's three methods, in the order of its tables: soft + hard iron (section II), hard iron only
#: (section III), pseudo-calibration (section IV).
PAPER_METHODS: tuple[str, ...] = ("ellipsoid", "sphere", "minmax")


@dataclass(frozen=True, eq=False)
class MethodResult:
    """The outcome of one method on one set of samples: a calibration and its score, or why it failed.

    Attributes
    ----------
    method : str
        Name of the method in ``magfit.METHODS``.
    calibration : Calibration or None
        The fitted calibration, ``None`` when the fit failed.
    evaluation : Evaluation or None
        The paper's metric on the same samples (dimensionless), ``None`` when the fit failed.
    error : str or None
        The one-line reason of the failure (the :class:`~magfit.CalibrationError` message).
    seconds : float
        Wall-clock time of the fit, seconds.
    """

    method: str
    calibration: Calibration | None
    evaluation: Evaluation | None
    error: str | None
    seconds: float

    @property
    def ok(self) -> bool:
        """True when the method produced a calibration."""
        return self.calibration is not None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary: the calibration (schema of :meth:`Calibration.to_dict`) and the score."""
        if self.calibration is None or self.evaluation is None:
            return {"method": self.method, "ok": False, "error": self.error}
        return {
            "method": self.method,
            "ok": True,
            "evaluation": self.evaluation.to_dict(),
            "semi_axes": self.calibration.semi_axes.tolist(),
            "calibration": self.calibration.to_dict(),
        }


@dataclass(frozen=True, eq=False)
class Comparison:
    """The results of several methods on the same samples, in the order they were asked for.

    Attributes
    ----------
    n_samples : int
        Number of samples every method was fitted to and scored on.
    results : tuple of MethodResult
        One per method.
    """

    n_samples: int
    results: tuple[MethodResult, ...] = field(default_factory=tuple)

    @property
    def methods(self) -> tuple[str, ...]:
        """The method names, in order."""
        return tuple(result.method for result in self.results)

    @property
    def any_succeeded(self) -> bool:
        """True when at least one method produced a calibration."""
        return any(result.ok for result in self.results)

    def __getitem__(self, method: str) -> MethodResult:
        for result in self.results:
            if result.method == method:
                return result
        raise KeyError(f"{method!r} is not in this comparison; it holds: {', '.join(self.methods)}")

    def __iter__(self) -> Iterator[MethodResult]:
        return iter(self.results)

    def __len__(self) -> int:
        return len(self.results)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: the sample count and one entry per method (see :meth:`MethodResult.to_dict`)."""
        return {"n_samples": self.n_samples, "results": [result.to_dict() for result in self.results]}


def compare(
    samples: ArrayLike,
    methods: Sequence[str] = PAPER_METHODS,
    *,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    allow_undetermined: bool = False,
    streams: Mapping[str, ArrayLike] | None = None,
) -> Comparison:
    """Fit each method to the same samples and score it with the paper's sphere-distance metric.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw magnetometer samples, one (x, y, z) per row, any unit.
    methods : sequence of str
        Names in ``magfit.METHODS``; the paper's three by default.
    options : mapping, optional
        Per-method keyword options, e.g. ``{"minmax": {"centre": "midrange"}}``.
    allow_undetermined : bool
        Score a fit the samples do not support instead of reporting its refusal (the paper's tables,
        which show every method on every case; the refusal is then in ``calibration.support``).
    streams : mapping, optional
        What was recorded beside the samples, one row per sample, by the option name the methods take
        (``reference``: the expected field in the vehicle frame; ``gyro``: body rates, rad/s; ``time_s``).
        A method that needs a stream not given is not run: its result says which and where it comes from.

    Returns
    -------
    Comparison
        One :class:`MethodResult` per method, in order. A method whose fit raises
        :class:`~magfit.CalibrationError` gets its reason instead of a calibration.

    Raises
    ------
    SampleError
        The samples are not an (N, 3) array of finite numbers (no method could use them).
    OptionError
        An unknown method, a method listed twice, an option for a method not compared, or an unknown
        option: checked before any fit runs.
    """
    array = as_samples(samples)
    names = list(methods)
    if not names:
        raise OptionError("compare() needs at least one method")
    for name in names:
        get_method(name)  # an unknown name fails here, listing the valid ones
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise OptionError(f"methods listed more than once: {', '.join(duplicates)}")
    options = dict(options or {})
    stray = sorted(set(options) - set(names))
    if stray:
        raise OptionError(f"options given for methods not compared: {', '.join(stray)}")
    for name, method_options in options.items():
        unknown = sorted(set(method_options) - set(get_method(name).options))
        if unknown:
            valid = ", ".join(get_method(name).options) or "none"
            raise OptionError(f"method {name!r} has no option {', '.join(map(repr, unknown))}; valid options: {valid}")

    streams = dict(streams or {})
    results = []
    for name in names:
        spec = get_method(name)
        missing = [need for need in spec.needs if need not in streams and need not in options.get(name, {})]
        if missing:
            results.append(MethodResult(name, None, None, _not_run(name, missing), 0.0))
            continue
        given: dict[str, Any] = {option: value for option, value in streams.items() if option in spec.options}
        start = time.perf_counter()
        try:
            calibration = fit(
                array, method=name, allow_undetermined=allow_undetermined, **given, **dict(options.get(name, {}))
            )
        except CalibrationError as error:
            results.append(MethodResult(name, None, None, str(error), time.perf_counter() - start))
            continue
        seconds = time.perf_counter() - start
        results.append(MethodResult(name, calibration, evaluate(calibration, array), None, seconds))
    return Comparison(int(array.shape[0]), tuple(results))


#: What each stream a method may need is, and where a recording holds it, for the words of a method not run.
_STREAM_WORDS = {
    "reference": "the field expected at each sample in the vehicle frame (a flight log or bag with the attitude "
    "and a position)",
    "gyro": "the gyroscope's rates beside each sample (a log or bag with the gyroscope)",
    "time_s": "the samples' time stamps (a log or bag)",
    "down": "the vertical in the vehicle frame from the roll and pitch (a flight log or bag with the attitude)",
}
#: The ``magfit calibrate`` option that reads each stream from a samples file's columns, with its placeholder.
_STREAM_OPTIONS = {"reference": ("reference", "X,Y,Z"), "gyro": ("gyro", "X,Y,Z"), "time_s": ("time", "T")}


def _not_run(method: str, missing: list[str]) -> str:
    """Why a method that needs more than the samples was not run, and how to give it, in the reader's words
    (built when said: ``streams={...}`` in Python, the samples file's columns on the command line)."""
    needs = "; ".join(_STREAM_WORDS.get(need, need) for need in missing)
    if audience() == "command line":
        chosen = [("method", method), *(_STREAM_OPTIONS[need] for need in missing if need in _STREAM_OPTIONS)]
        how = (
            "; a samples file gives them in columns named as docs/file-formats.md lists, or in any columns "
            f"with {command_line('calibrate', 'FILE', chosen)}"
        )
    else:
        how = "; or give them: streams={" + ", ".join(f"{need!r}: ..." for need in missing) + "}"
    return f"not run: the {method} method needs {needs}{how}"


#: Rows scored at a time: the temporaries of one slice stay at a few MB whatever the reader's chunk size.
EVALUATION_SLICE = 1 << 16


def _slices(chunks: Iterable[ArrayLike]) -> Iterator[NDArray[np.float64]]:
    for chunk in chunks:
        array = np.asarray(chunk)
        if array.ndim != 2:  # let sphere_distances name the wrong shape
            yield array
            continue
        for start in range(0, max(array.shape[0], 1), EVALUATION_SLICE):
            yield array[start : start + EVALUATION_SLICE]


def evaluate_chunks(calibration: Calibration, chunks: Iterable[ArrayLike]) -> Evaluation:
    """The paper's metric (:func:`magfit.evaluate`) over a stream of sample chunks, in bounded memory.

    Parameters
    ----------
    calibration : Calibration
    chunks : iterable of array_like, each shape (n, 3)
        Raw samples in the calibration's input units (e.g. a file read chunk by chunk).

    Returns
    -------
    Evaluation
        Equal to ``evaluate(calibration, np.concatenate(chunks))`` to round-off. The mean and the
        variance are merged chunk by chunk with the pairwise update of Chan, Golub and LeVeque, so no
        large sum of squares cancels.

    Raises
    ------
    SampleError
        A chunk is not (n, 3) finite numbers, or the stream holds no samples.
    """
    n = 0
    mean = 0.0
    m2 = 0.0  # sum of squared deviations from the running mean
    abs_sum = 0.0
    square_sum = 0.0
    max_abs = 0.0
    for chunk in _slices(chunks):
        distances = sphere_distances(calibration, chunk)
        k = int(distances.size)
        if k == 0:
            continue
        chunk_mean = float(distances.mean())
        chunk_m2 = float(np.sum((distances - chunk_mean) ** 2))
        total = n + k
        delta = chunk_mean - mean
        mean += delta * k / total
        m2 += chunk_m2 + delta * delta * n * k / total
        n = total
        magnitude = np.abs(distances)
        abs_sum += float(magnitude.sum())
        square_sum += float(np.sum(distances**2))
        max_abs = max(max_abs, float(magnitude.max()))
    if n == 0:
        raise SampleError("evaluate_chunks() received no samples: the stream of chunks was empty")
    return Evaluation(
        n=n,
        mean=mean,
        std=float(np.sqrt(m2 / n)),
        mean_abs=abs_sum / n,
        rms=float(np.sqrt(square_sum / n)),
        max_abs=max_abs,
    )
