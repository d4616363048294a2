"""Trust campaign: does every accepted fit's stated heading one-sigma cover its true heading error?

Run (from the checkout, in magfit's development environment)::

    python benchmarks/campaign.py                 # the default run, 6 seeds per kind: about a minute
    python benchmarks/campaign.py --trials 1      # one seed per kind

It simulates the kinds of data the second fuzz campaign found wrong calibrations on, each with a known
truth (the paper's eq. 1): a sensor clipped at its full scale, half a sphere of directions with mild soft
iron, clusters of a few attitudes, tilt cones (a vehicle that cannot be turned over), coarse integer
counts, level flight with banked turns; then level turns only with strong horizontal soft iron, tilt
within ±5-10°, flight with a drifting field, eddy currents and induced fields, and a cap of 10 % of the
directions. It fits every magnitude-only method to each trial (as
``magfit.fit`` does by default: the verdict with the full diagnostics) and scores each returned
("supported" or "weak") calibration against the truth with the accuracy benchmark's heading error
(``accuracy.heading_error_deg``: RMS over level headings, the unobservable rotation removed). A fit
*exceeds* when that error is more than :data:`COVER` times its stated heading one-sigma
(``calibration.diagnostics.uncertainty.heading_sigma_deg``) and more than :data:`FLOOR_DEG` (below it a
heading error matters to nobody). The target is no such fit. Refusals are counted beside.

Writes ``benchmarks/results/campaign.md`` (``--output``): the command, the counts per kind and method, and
every exceeding fit with its seed, so that it can be rerun alone (``--kinds``, ``--methods``, ``--seed``).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

import magfit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import heading_error_deg

#: An accepted fit must be within this many stated one-sigmas of the true heading.
COVER = 3.0
#: Heading errors below this (degrees) are not counted against the stated one-sigma.
FLOOR_DEG = 0.1
#: The magnitude-only methods (vector and gyro need a reference or body rates: benchmarks/accuracy_vehicle.py).
METHODS = tuple(name for name, spec in magfit.METHODS.items() if not spec.needs)

Maker = Callable[[np.random.Generator, int], tuple[magfit.Simulation, NDArray[np.float64]]]


def mild_soft_iron(rng: np.random.Generator, amplitude: float) -> NDArray[np.float64]:
    """A symmetric soft-iron matrix ``I + E``, E's entries uniform within ±``amplitude`` (symmetrised)."""
    spread = rng.uniform(-amplitude, amplitude, (3, 3))
    return np.asarray(np.eye(3) + (spread + spread.T) / 2.0)


def hemisphere_attitudes(
    n: int,
    rng: np.random.Generator,
    inclination_deg: float = 64.0,
    share: float = 0.5,
    axis: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Uniform attitudes (roll, pitch, yaw; degrees) whose field direction in the sensor frame lies in the cap
    around ``axis`` (default +z) covering ``share`` of the sphere (a half: z > 0)."""
    from scipy.spatial.transform import Rotation

    delta = np.radians(inclination_deg)
    earth = np.array([np.cos(delta), 0.0, np.sin(delta)])
    toward = np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    kept: list[NDArray[np.float64]] = []
    while sum(len(k) for k in kept) < n:
        rotations = Rotation.random(max(4 * n, int(4 * n / share)), random_state=rng)
        seen = rotations.as_matrix() @ earth
        kept.append(np.degrees(rotations.as_euler("XYZ"))[seen @ toward > 1.0 - 2.0 * share])
    return np.concatenate(kept)[:n]


def _saturated(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """A sensor clipped at 1.4 times the field, its offset 0.8 times the field on each axis (±, scaled 0.5-1)."""
    offset = 0.8 * rng.choice([-1.0, 1.0], 3) * rng.uniform(0.5, 1.0, 3)
    sim = magfit.simulate(2000, soft_iron=mild_soft_iron(rng, 0.1), hard_iron=offset, noise=0.01, seed=seed)
    return sim, np.clip(sim.samples, -1.4, 1.4)


def _hemisphere(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Half a sphere of directions, soft iron within ±2.5 % to ±25 %."""
    attitudes = hemisphere_attitudes(1500, rng)
    sim = magfit.simulate(
        1500, soft_iron=mild_soft_iron(rng, rng.uniform(0.025, 0.25)), hard_iron=rng.uniform(-0.5, 0.5, 3),
        noise=0.005, orientations=attitudes, seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _clusters(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """A sensor held still in 4 to 12 attitudes, each for a stretch, with a few degrees of wobble."""
    from scipy.spatial.transform import Rotation

    k = int(rng.integers(4, 13))
    centres = np.degrees(Rotation.random(k, random_state=rng).as_euler("XYZ"))
    attitudes = np.repeat(centres, 1200 // k + 1, axis=0)[:1200] + rng.normal(0.0, 3.0, (1200, 3))
    sim = magfit.simulate(
        1200, soft_iron=mild_soft_iron(rng, 0.1), hard_iron=rng.uniform(-0.5, 0.5, 3), noise=0.01,
        orientations=attitudes, seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _tilt_cone(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Full yaw, roll and pitch within ±5° to ±45°."""
    sim = magfit.simulate(
        1500, soft_iron=mild_soft_iron(rng, 0.15), hard_iron=rng.uniform(-0.5, 0.5, 3), noise=0.01,
        orientations="restricted", max_tilt_deg=float(rng.choice([5.0, 10.0, 20.0, 30.0, 45.0])), seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _quantised(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """A full tumble read in coarse integer counts: a field of 20 to 80 counts."""
    field = float(rng.uniform(20.0, 80.0))
    sim = magfit.simulate(
        1500, soft_iron=mild_soft_iron(rng, 0.15), hard_iron=field * rng.uniform(-0.5, 0.5, 3),
        field_strength=field, noise=0.3, resolution=1.0, seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _flight(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Level flight with banked turns within ±15° to ±35°, a field drifting by up to ±0.5 %."""
    sim = magfit.simulate(
        4000, soft_iron=mild_soft_iron(rng, 0.05), hard_iron=rng.uniform(-0.4, 0.4, 3), noise=0.005,
        orientations="flight", max_tilt_deg=float(rng.uniform(15.0, 35.0)), field_drift=float(rng.uniform(0, 0.005)),
        seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _level_turns(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Level turns only (yaw), strong horizontal soft iron: scales 0.9-1.4 on x and y, 0.9-1.1 on z."""
    soft_iron = np.diag([*rng.uniform(0.9, 1.4, 2), rng.uniform(0.9, 1.1)])
    sim = magfit.simulate(
        3000, soft_iron=soft_iron, hard_iron=rng.uniform(-3.0, 3.0, 3), noise=0.01,
        inclination_deg=float(rng.choice([-1.0, 1.0]) * rng.uniform(20.0, 70.0)), orientations="yaw", seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _shallow_tilt(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Full yaw, roll and pitch within ±5° or ±10°, soft iron within ±5 % to ±30 %."""
    sim = magfit.simulate(
        1500, soft_iron=mild_soft_iron(rng, rng.uniform(0.05, 0.3)), hard_iron=rng.uniform(-0.5, 0.5, 3),
        noise=0.01, orientations="restricted", max_tilt_deg=float(rng.choice([5.0, 10.0])), seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _drifting_flight(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """Flight with banked turns within ±20° to ±60°, the field drifting by up to ±2 %, eddy currents
    N(0, 0.01 s) (eq. 1e of :mod:`magfit.simulate`) and an aircraft's induced field (±3 %, cross ±1.5 %)."""
    cross = rng.uniform(-0.015, 0.015, 3)
    soft_iron = np.diag(1.0 + rng.uniform(-0.03, 0.03, 3))
    soft_iron[[0, 0, 1], [1, 2, 2]] = cross
    soft_iron[[1, 2, 2], [0, 0, 1]] = cross
    sim = magfit.simulate(
        6000, soft_iron=soft_iron, hard_iron=rng.uniform(-0.4, 0.4, 3), noise=0.005, orientations="flight",
        max_tilt_deg=float(rng.uniform(20.0, 60.0)), field_drift=float(rng.uniform(0.0, 0.02)),
        eddy_current=rng.normal(0.0, 0.01, (3, 3)), seed=seed,
    )  # fmt: skip
    return sim, sim.samples


def _cap(rng: np.random.Generator, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """A cap of 10 % of the directions around a random axis, soft iron within ±10 %."""
    axis = rng.normal(size=3)
    attitudes = hemisphere_attitudes(2000, rng, share=0.1, axis=axis)
    sim = magfit.simulate(
        2000, soft_iron=mild_soft_iron(rng, 0.1), hard_iron=rng.uniform(-0.5, 0.5, 3), noise=0.05,
        orientations=attitudes, seed=seed,
    )  # fmt: skip
    return sim, sim.samples


KINDS: dict[str, Maker] = {
    "saturated": _saturated,
    "hemisphere": _hemisphere,
    "clusters": _clusters,
    "tilt cone": _tilt_cone,
    "quantised": _quantised,
    "flight": _flight,
    "level turns": _level_turns,
    "shallow tilt": _shallow_tilt,
    "drifting flight": _drifting_flight,
    "cap 10 %": _cap,
}


@dataclass(frozen=True)
class Outcome:
    """One fit of one method to one trial."""

    kind: str
    seed: int
    method: str
    verdict: str  # "supported", "weak", "refused"
    codes: tuple[str, ...]
    error_deg: float | None = None
    stated_deg: float | None = None
    offset_z: float | None = None  # the worst axis's |fitted − true offset| / stated offset one-sigma

    @property
    def exceeds(self) -> bool:
        """Accepted, and its true heading error beyond COVER stated one-sigmas (and FLOOR_DEG)."""
        if self.verdict == "refused" or self.error_deg is None or self.error_deg <= FLOOR_DEG:
            return False
        return self.stated_deg is None or self.error_deg > COVER * self.stated_deg


def trial(kind: str, seed: int) -> tuple[magfit.Simulation, NDArray[np.float64]]:
    """The simulation of ``kind`` for ``seed`` and the samples the fits see (clipped, for ``saturated``)."""
    rng = np.random.default_rng([seed, list(KINDS).index(kind)])
    return KINDS[kind](rng, seed)


def score(kind: str, seed: int, method: str, sim: magfit.Simulation, samples: NDArray[np.float64]) -> Outcome:
    """Fit ``method`` as ``magfit.fit`` does by default and compare the result with the truth."""
    try:
        calibration = magfit.fit(samples, method)
    except magfit.CalibrationError as error:
        return Outcome(kind, seed, method, "refused", tuple(error.codes))
    support = calibration.support
    assert support is not None  # every fit is judged
    report = calibration.diagnostics
    stated = report.uncertainty.heading_sigma_deg if report is not None and report.uncertainty else None
    offset_z = None
    if report is not None and report.uncertainty is not None and report.uncertainty.offset_sigma is not None:
        sigma = np.asarray(report.uncertainty.offset_sigma)
        offset_z = float(np.max(np.abs(calibration.offset - sim.truth.offset) / sigma))
    return Outcome(
        kind, seed, method, support.verdict, support.codes, heading_error_deg(calibration, sim), stated, offset_z
    )


def run(kinds: list[str], methods: list[str], seeds: list[int], progress: bool = False) -> list[Outcome]:
    outcomes = []
    for kind in kinds:
        for seed in seeds:
            sim, samples = trial(kind, seed)
            for method in methods:
                outcomes.append(score(kind, seed, method, sim, samples))
                if progress and outcomes[-1].exceeds:
                    o = outcomes[-1]
                    print(f"  exceeds: {kind} seed {seed} {method}: {o.error_deg:.2f}° vs ±{o.stated_deg}", flush=True)
    return outcomes


def _grid(
    outcomes: list[Outcome], kinds: list[str], methods: list[str], cell: Callable[[list[Outcome]], str]
) -> list[str]:
    """A table's rows: one per kind, a ``cell`` of that kind's fits per method."""
    return [
        f"| {kind} | "
        + " | ".join(cell([o for o in outcomes if o.kind == kind and o.method == method]) for method in methods)
        + " |"
        for kind in kinds
    ]


def _heading_cell(mine: list[Outcome]) -> str:
    """Accepted / fits, then those exceeding (the worst ratio of true heading error to stated one-sigma)."""
    ok = [o for o in mine if o.verdict != "refused"]
    ratios = [o.error_deg / o.stated_deg for o in ok if o.error_deg is not None and o.stated_deg]
    worst = f" ({max(ratios):.1f}x)" if ratios else ""
    return f"{len(ok)}/{len(mine)}, {sum(o.exceeds for o in ok)}{worst}"


def _offset_cell(mine: list[Outcome]) -> str:
    """Fits whose worst offset axis is beyond COVER one-sigmas / fits with an offset one-sigma (the worst ratio)."""
    zs = [o.offset_z for o in mine if o.offset_z is not None]
    return f"{sum(z > COVER for z in zs)}/{len(zs)} ({max(zs):.1f})" if zs else "—"


def report(outcomes: list[Outcome], command: str, seconds: float) -> str:
    kinds = list(dict.fromkeys(o.kind for o in outcomes))
    methods = list(dict.fromkeys(o.method for o in outcomes))
    exceeding = [o for o in outcomes if o.exceeds]
    accepted = [o for o in outcomes if o.verdict != "refused"]
    lines = [
        "# Trust campaign: accepted fits whose true heading error exceeds 3x the stated one-sigma",
        "",
        f"`{command}` — {time.strftime('%Y-%m-%d')}, {seconds:.0f} s, magfit {magfit.__version__}, "
        f"numpy {np.__version__}, Python {platform.python_version()}",
        "",
        f"**{len(exceeding)} of {len(accepted)} accepted fits exceed** (true level-heading error > {COVER:g} x the "
        f"stated heading one-sigma and > {FLOOR_DEG:g}°); {len(outcomes) - len(accepted)} of {len(outcomes)} fits "
        "refused. Target: 0 exceed.",
        "",
        "Cells: accepted / fits, then exceeding (worst ratio of true error to stated one-sigma among accepted fits).",
        "The offset table below: the worst axis's offset error over its stated offset one-sigma.",
        "",
        "| kind | " + " | ".join(methods) + " |",
        "|---|" + "---|" * len(methods),
    ]
    lines += _grid(outcomes, kinds, methods, _heading_cell)
    offsets = [o.offset_z for o in accepted if o.offset_z is not None]
    lines += [
        "",
        "## Offset: true error over the stated offset one-sigma (worst axis)",
        "",
        "Cells: the share of accepted fits whose worst axis is beyond 3 one-sigmas, then the worst ratio. "
        + (
            f"Overall {sum(z > COVER for z in offsets)} of {len(offsets)} beyond {COVER:g} (a Gaussian's worst of 3 "
            "axes: about 0.8 %), median "
            f"{float(np.median(offsets)):.2f}."
            if offsets
            else ""
        ),
        "",
        "| kind | " + " | ".join(methods) + " |",
        "|---|" + "---|" * len(methods),
    ]
    lines += _grid(outcomes, kinds, methods, _offset_cell)
    lines += ["", "## Exceeding fits", ""]
    if not exceeding:
        lines.append("None.")
    for o in exceeding:
        lines.append(
            f"- {o.kind}, seed {o.seed}, {o.method}: {o.verdict} {list(o.codes)}, true {o.error_deg:.2f}° against "
            f"±{o.stated_deg if o.stated_deg is None else round(o.stated_deg, 3)}°"
        )
    refusals: dict[str, int] = {}
    for o in outcomes:
        if o.verdict == "refused":
            for code in o.codes or ("(none)",):
                refusals[code] = refusals.get(code, 0) + 1
    lines += ["", "## Refusal codes", ""]
    lines += [f"- {code}: {count}" for code, count in sorted(refusals.items(), key=lambda item: -item[1])]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--trials", type=int, default=6, help="seeds per kind (default 6)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--kinds", default=",".join(KINDS), help="comma-separated kinds")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated magnitude-only methods")
    parser.add_argument("--output", type=Path, default=Path(__file__).resolve().parent / "results" / "campaign.md")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    kinds, methods = args.kinds.split(","), args.methods.split(",")
    unknown = sorted(set(kinds) - set(KINDS)) + sorted(set(methods) - set(METHODS))
    if unknown:
        parser.error(f"unknown kinds or methods: {', '.join(unknown)}")
    started = time.perf_counter()
    outcomes = run(kinds, methods, list(range(args.seed, args.seed + args.trials)), progress=True)
    command = "python benchmarks/campaign.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = report(outcomes, command.strip(), time.perf_counter() - started)
    print(text)
    if not args.no_write:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text, encoding="utf-8")
    return 1 if any(o.exceeds for o in outcomes) else 0


if __name__ == "__main__":
    raise SystemExit(main())
