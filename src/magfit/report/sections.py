"""A report's sections built from magfit's results: a comparison of methods, an experiment's runs."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from numpy.typing import ArrayLike

from ..calibration import Calibration
from ..compare import PAPER_METHODS, Comparison, compare
from ._html import ReportSection

if TYPE_CHECKING:
    from ..experiment import Experiment

__all__ = ["compare_section", "experiment_sections", "section_from_comparison"]


def section_from_comparison(
    title: str,
    samples: ArrayLike,
    comparison: Comparison,
    *,
    unit: str | None = None,
    truth: Calibration | None = None,
    published: Mapping[str, tuple[float, float]] | None = None,
    notes: Sequence[str] = (),
    diagnostics: Mapping[str, Any] | None = None,
) -> ReportSection:
    """A report section from a :func:`magfit.compare` result: its fits, and its failures with their reasons."""
    return ReportSection(
        title=title,
        samples=samples,  # type: ignore[arg-type]  # validated to an (N, 3) float array by ReportSection
        calibrations=tuple(result.calibration for result in comparison if result.calibration is not None),
        unit=unit,
        failures={result.method: result.error or "unknown reason" for result in comparison if not result.ok},
        truth=truth,
        published=dict(published or {}),
        notes=tuple(notes),
        diagnostics=diagnostics,
    )


def compare_section(
    title: str,
    samples: ArrayLike,
    methods: Sequence[str] = PAPER_METHODS,
    *,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    unit: str | None = None,
    truth: Calibration | None = None,
    notes: Sequence[str] = (),
) -> ReportSection:
    """Fit ``methods`` to ``samples`` with :func:`magfit.compare` and make a report section of the result.

    Parameters
    ----------
    title : str
        What the data are (a file name).
    samples : array_like, shape (N, 3)
        Raw samples, input units.
    methods : sequence of str
        Methods to compare; the paper's three by default. The first that succeeds is the main one.
    options : mapping, optional
        Per-method options, as for :func:`magfit.compare`.
    unit : str, optional
        Input unit name, for labels.
    truth : Calibration, optional
        The true calibration (simulated data).
    notes : sequence of str
        Paragraphs shown under the section title.
    """
    comparison = compare(samples, methods, options=options)
    return section_from_comparison(title, samples, comparison, unit=unit, truth=truth, notes=notes)


def experiment_sections(experiment: Experiment) -> list[ReportSection]:
    """One report section per case of the paper's simulated experiment (``magfit demo --report``).

    Each section carries the simulation's true calibration and the paper's published mean and std
    (measured on the authors' real recordings) beside the simulated ones.
    """
    from ..experiment import DISTURBANCE_LABELS, PAPER_DISTANCES, SENSOR_LABELS

    sections = []
    for case in experiment.cases:
        published = {
            method: PAPER_DISTANCES[case.disturbance, method, case.sensor]
            for method in experiment.methods
            if (case.disturbance, method, case.sensor) in PAPER_DISTANCES
        }
        sections.append(
            section_from_comparison(
                f"{SENSOR_LABELS[case.sensor]}, {DISTURBANCE_LABELS[case.disturbance].lower()} (simulated)",
                case.simulation.samples,
                case.comparison,
                unit=case.scenario.unit,
                truth=case.simulation.truth,
                published=published,
                notes=(
                    f"{experiment.n_samples:,} samples simulated from eq. (1) with the ellipsoid semi-axes "
                    f"{tuple(case.scenario.semi_axes)} and hard-iron offset {tuple(case.scenario.hard_iron)} "
                    "the paper reports for this case (seed "
                    f"{experiment.seed}). The published mean and std were measured on the authors' real "
                    "recordings.",
                ),
            )
        )
    return sections
