"""The state of a live calibration: the samples so far, an even subset of them, the latest fit and its verdict.

Samples arrive in batches (:meth:`Session.add`, from the reader thread); fits run on demand
(:meth:`Session.refit`, from the fitting thread); views ask for a :meth:`Session.snapshot`. A lock guards
the shared state, and a fit runs outside it, on a copy, so that reading never waits for a fit.

Every sample is kept (the final fit and a re-centred subset need them), and so is their
:class:`~magfit.Statistics`. The fits run on a bounded subset in which every direction weighs the same
(:class:`magfit.sampling.EvenSampler`, fed as the samples come): a hand that lingers in one attitude does
not pull the fit, and a fit costs the same after ten seconds as after ten minutes. The subset's cells are
taken in the frame of the current fit; when a fit moves that frame (its offset by more than 5 % of the
field, or its shape by more than 5 %), the subset is rebuilt from all samples in the new frame.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..diagnostics.coverage import Coverage, coverage, partition
from ..errors import CalibrationError
from ..fit import fit, refit
from ..sampling import EvenSampler, direction_frame, even_subsample
from ..statistics import Statistics

__all__ = ["FINAL_FIT_SAMPLES", "FIT_SAMPLES", "FitResult", "Session", "Snapshot", "Thresholds", "Verdict"]

#: Samples of the even subset each live fit runs on. Measured (benchmarks/results/live.md): one `auto` fit
#: costs 79 ms on 250 samples, 125 ms on 2000 and 151 ms on 4000 (mostly fixed cost), and 2000 samples in
#: 400 cells of about 10° keep five per visited direction, which steadies the heading uncertainty.
FIT_SAMPLES = 2000
#: A full fit (a new model choice for ``auto``) at most this often; in between, the last fit's model is
#: refitted to the new samples (:func:`magfit.refit`: 8 ms against 73 ms for a full ``auto`` on 2000
#: samples), so the view's fit follows the hand several times a second within its CPU budget.
FULL_FIT_SECONDS = 3.0
#: Samples of the even subsample the final calibration is fitted on (as ``calibrate --even`` would).
FINAL_FIT_SAMPLES = 20_000
#: Cells of the coverage map and verdict (100, as MotionCal's gap figure; magfit's diagnostics use the same).
COVERAGE_CELLS = 100
#: Fewest samples before a fit is tried (the full model has 9 parameters; fewer is noise).
MIN_FIT_SAMPLES = 50
#: A fit whose frame moved more than this (offset, relative to the field; shape, relative) re-centres the subset.
_RECENTRE = 0.05


@dataclass(frozen=True)
class Thresholds:
    """When a live calibration is good enough to save; every test is shown in the view.

    Attributes
    ----------
    min_coverage : float
        Share of the 100 equal-area directions the field was seen along (MotionCal asks for gaps
        below 15 %, i.e. 0.85).
    max_heading_sigma_deg : float
        Largest one-sigma heading uncertainty at level attitude, degrees (``cal.diagnostics.uncertainty``).
    """

    min_coverage: float = 0.85
    max_heading_sigma_deg: float = 0.5


@dataclass(frozen=True)
class FitResult:
    """One live fit: the calibration or the reason there is none, and what it cost."""

    calibration: Calibration | None
    error: str | None
    n_used: int
    n_seen: int
    cpu_seconds: float
    finished: float


@dataclass(frozen=True)
class Verdict:
    """Whether the latest fit is good enough, with each check as (label, value, threshold, passed)."""

    good: bool
    checks: tuple[tuple[str, str, str, bool], ...]
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class Snapshot:
    """What a view shows, copied out of the session under its lock."""

    n_samples: int
    rate_hz: float
    elapsed: float
    reached: NDArray[np.bool_]  # per cell of partition(COVERAGE_CELLS)
    coverage: Coverage | None
    fit: FitResult | None
    verdict: Verdict
    fits_done: int
    fit_cpu_seconds: float
    last_sample: NDArray[np.float64] | None
    messages: tuple[str, ...] = field(default=())


class Session:
    """Samples, their even subset and the latest fit of one live calibration.

    Parameters
    ----------
    thresholds : Thresholds
        The "good enough" tests.
    fit_samples : int
        Size of the even subset the live fits use.
    method : str
        The fit (``auto`` by default); ``options`` go to :func:`magfit.fit`.
    clock : callable
        Seconds, monotonic (tests may pass their own).
    """

    def __init__(
        self,
        *,
        thresholds: Thresholds | None = None,
        fit_samples: int = FIT_SAMPLES,
        method: str = "auto",
        options: dict[str, Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.thresholds = thresholds or Thresholds()
        self.fit_samples = fit_samples
        self.method = method
        self.options = dict(options or {})
        self._clock = clock
        self._lock = threading.Lock()
        self._reset_state()

    def _reset_state(self) -> None:
        self._blocks: list[NDArray[np.float64]] = []
        self._n = 0
        self._statistics = Statistics()
        self._sampler: EvenSampler | None = None
        self._fit: FitResult | None = None
        self._fits_done = 0
        self._fit_cpu = 0.0
        self._started = self._clock()
        self._rate_window: list[tuple[float, int]] = []
        self._generation = 0  # bumped by reset(): a fit started before a reset is discarded
        self._full_fit_at = -math.inf  # when the last full fit (a model choice) was made

    def reset(self) -> None:
        """Forget every sample and fit (the ``reset`` key); a fit under way is discarded when it ends."""
        with self._lock:
            generation = self._generation + 1
            self._reset_state()
            self._generation = generation

    # ------------------------------------------------------------------ samples in

    def add(self, samples: NDArray[np.float64]) -> None:
        """Append (n, 3) samples (reader thread)."""
        if samples.shape[0] == 0:
            return
        now = self._clock()
        with self._lock:
            self._blocks.append(samples)
            self._n += samples.shape[0]
            self._statistics.update(samples)
            if self._sampler is not None:
                self._sampler.update(samples)
            self._rate_window.append((now, self._n))
            while len(self._rate_window) > 2 and now - self._rate_window[0][0] > 2.0:
                self._rate_window.pop(0)

    @property
    def n_samples(self) -> int:
        return self._n

    def samples(self) -> NDArray[np.float64]:
        """Every sample so far, (N, 3) (consolidated into one block)."""
        with self._lock:
            return self._all()

    def _all(self) -> NDArray[np.float64]:
        if len(self._blocks) > 1:
            self._blocks = [np.concatenate(self._blocks)]
        return self._blocks[0] if self._blocks else np.empty((0, 3))

    # ------------------------------------------------------------------ fitting

    def refit(self) -> FitResult | None:
        """Fit the even subset now (fitting thread); None when there are too few samples or none new."""
        with self._lock:
            if self._n < MIN_FIT_SAMPLES or (self._fit is not None and self._fit.n_seen == self._n):
                return None
            if self._sampler is None:
                self._sampler = self._new_sampler(*direction_frame(self._statistics))
            subset = self._sampler.samples
            n_seen = self._n
            generation = self._generation
            previous = self._fit.calibration if self._fit is not None else None
        full = previous is None or self._clock() - self._full_fit_at >= FULL_FIT_SECONDS
        start = time.thread_time()
        try:
            if full or previous is None:
                calibration: Calibration | None = fit(subset, self.method, diagnostics="quick", **self.options)
                self._full_fit_at = self._clock()
            else:  # the model chosen last time, refitted to the new samples and judged again (a few ms)
                calibration = refit(previous, subset)
            error = None
        except CalibrationError as failure:
            calibration, error = None, str(failure)
            self._full_fit_at = -math.inf  # the next fit chooses again
        cost = time.thread_time() - start
        result = FitResult(calibration, error, subset.shape[0], n_seen, cost, self._clock())
        with self._lock:
            if generation != self._generation:
                return None
            self._fit = result
            self._fits_done += 1
            self._fit_cpu += cost
            if calibration is not None and self._moved(calibration):
                self._sampler = self._new_sampler(calibration.offset, calibration.matrix)
        return result

    def _new_sampler(self, centre: NDArray[np.float64], shape: NDArray[np.float64]) -> EvenSampler:
        sampler = EvenSampler(self.fit_samples, centre=centre, shape=shape)
        if self._n:
            sampler.update(self._all())
        return sampler

    def _moved(self, calibration: Calibration) -> bool:
        """True when the fit's frame is far from the subset's (see the module docstring)."""
        assert self._sampler is not None
        shift = np.linalg.norm(calibration.offset - self._sampler.centre) / calibration.field_strength
        if self._sampler.shape is None:
            return True
        old = self._sampler.shape / np.cbrt(abs(np.linalg.det(self._sampler.shape)))
        change = np.linalg.norm(calibration.matrix - old) / np.linalg.norm(calibration.matrix)
        return bool(shift > _RECENTRE or change > _RECENTRE)

    def final_calibration(self) -> Calibration:
        """The calibration to save: one fit on an even subsample of every sample (at most 20 000).

        Raises
        ------
        CalibrationError
            When the samples cannot support the fit (too few, flat ...), with the reason.
        """
        with self._lock:
            samples = self._all()
            latest = self._fit.calibration if self._fit is not None else None
        if samples.shape[0] < MIN_FIT_SAMPLES:
            raise CalibrationError(
                f"only {samples.shape[0]} samples were received; turn the sensor in all directions for longer"
            )
        if latest is not None:
            keep = even_subsample(samples, max_samples=FINAL_FIT_SAMPLES, centre=latest.offset, shape=latest.matrix)
        else:
            keep = even_subsample(samples, max_samples=FINAL_FIT_SAMPLES)
        return fit(samples[keep], self.method, **self.options)

    def judge(self, calibration: Calibration) -> Verdict:
        """The verdict on ``calibration`` (the final one), its coverage counted over every sample as the view does."""
        samples = self.samples()
        cover = coverage(calibration.apply(samples), COVERAGE_CELLS) if samples.shape[0] else None
        n = samples.shape[0]
        return self.verdict(FitResult(calibration, None, calibration.n_samples or n, n, 0.0, 0.0), cover)

    # ------------------------------------------------------------------ what the view shows

    def snapshot(self) -> Snapshot:
        """The state now, for a view (cheap: the subset, not every sample, gives the coverage)."""
        with self._lock:
            now = self._clock()
            subset = self._sampler.samples if self._sampler is not None else self._tail(self.fit_samples)
            latest = self._fit
            window = list(self._rate_window)
            n = self._n
            last = self._blocks[-1][-1].copy() if self._blocks else None
            fits_done, fit_cpu, started = self._fits_done, self._fit_cpu, self._started
        rate = 0.0
        if len(window) >= 2 and window[-1][0] > window[0][0]:
            rate = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0])
        calibration = latest.calibration if latest is not None else None
        reached = np.zeros(COVERAGE_CELLS, dtype=bool)
        cover = None
        if subset.shape[0] and calibration is not None:
            directions = calibration.apply(subset)
            reached[partition(COVERAGE_CELLS).cell(directions)] = True
            cover = coverage(directions, COVERAGE_CELLS)
        return Snapshot(
            n_samples=n,
            rate_hz=rate,
            elapsed=now - started,
            reached=reached,
            coverage=cover,
            fit=latest,
            verdict=self.verdict(latest, cover),
            fits_done=fits_done,
            fit_cpu_seconds=fit_cpu,
            last_sample=last,
        )

    def subset(self) -> NDArray[np.float64]:
        """The even subset the fits use (before the first fit: the latest samples), (m, 3)."""
        with self._lock:
            return self._sampler.samples if self._sampler is not None else self._tail(self.fit_samples).copy()

    def _tail(self, count: int) -> NDArray[np.float64]:
        return self._all()[-count:]

    def verdict(self, latest: FitResult | None, cover: Coverage | None) -> Verdict:
        """The "good enough" checks of the latest fit against :attr:`thresholds`."""
        t = self.thresholds
        calibration = latest.calibration if latest is not None else None
        diagnostics = calibration.diagnostics if calibration is not None else None
        checks: list[tuple[str, str, str, bool]] = []
        if latest is None:
            checks.append(("fit", "waiting for samples", "a supported fit", False))
        elif calibration is None:
            checks.append(("fit", "refused", "a supported fit", False))
        else:
            checks.append(("fit", calibration.method if diagnostics is None else "supported", "a supported fit", True))
        share = cover.share if cover is not None else 0.0
        checks.append(("coverage", f"{100 * share:.0f} %", f">= {100 * t.min_coverage:.0f} %", share >= t.min_coverage))
        sigma = None
        if diagnostics is not None and diagnostics.uncertainty is not None:
            sigma = diagnostics.uncertainty.heading_sigma_deg
        checks.append(
            (
                "heading 1-sigma",
                "-" if sigma is None else f"{sigma:.2f} deg",
                f"<= {t.max_heading_sigma_deg:g} deg",
                sigma is not None and sigma <= t.max_heading_sigma_deg,
            )
        )
        warnings = diagnostics.warnings if diagnostics is not None else ()
        checks.append(("warnings", str(len(warnings)), "none", calibration is not None and not warnings))
        return Verdict(all(check[3] for check in checks), tuple(checks), tuple(warnings))
