"""``magfit simulate``: write samples of the paper's model (eq. 1) with a known calibration."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError
from ..simulate import DISTURBANCES, ORIENTATIONS, SENSORS, Simulation, scenario, simulate
from ._common import console, fail, float_list, refuse_overwriting_input, significant, vector

#: Output formats by file extension.
CSV_EXTENSIONS = (".csv", ".txt")
NPY_EXTENSIONS = (".npy",)
#: Significant digits written to CSV: far below any sensor's noise, and short lines.
CSV_DIGITS = 10


def write_samples(path: Path, samples: NDArray[np.float64]) -> None:
    """Write ``samples`` (N, 3) to ``path`` atomically: CSV with header ``mx,my,mz``, or ``.npy``."""
    from ..io import atomic_open

    suffix = path.suffix.lower()
    if suffix in NPY_EXTENSIONS:
        with atomic_open(path, "wb") as stream:
            np.save(stream, samples)
    else:
        with atomic_open(path, "w") as stream:
            np.savetxt(stream, samples, fmt=f"%.{CSV_DIGITS}g", delimiter=",", header="mx,my,mz", comments="")


@click.command("simulate")
@click.option("--sensor", type=click.Choice(SENSORS), default="mpu9250", show_default=True, help="Sensor of the paper.")
@click.option(
    "--disturbance",
    type=click.Choice(DISTURBANCES),
    default="none",
    show_default=True,
    help="The paper's situation: no perturbation, a piece of steel, a smartphone.",
)
@click.option("-n", "--samples", "n_samples", type=click.IntRange(min=1), required=True, help="Number of samples.")
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Output file: .csv/.txt (header mx,my,mz) or .npy.",
)
@click.option("--seed", type=int, default=None, help="Seed of the random draws (default: different every run).")
@click.option("--offset", callback=float_list(3), metavar="X,Y,Z", help="Hard-iron offset V, input units.")
@click.option("--matrix", callback=float_list(9), metavar="W11,...,W33", help="Soft-iron matrix W, 9 numbers, rows.")
@click.option("--noise", type=click.FloatRange(min=0), help="Noise std per axis, input units.")
@click.option("--field-strength", type=click.FloatRange(min=0, min_open=True), help="Field strength B, input units.")
@click.option(
    "--orientations",
    type=click.Choice(ORIENTATIONS),
    default="uniform",
    show_default=True,
    help="uniform: a full tumble; restricted: full yaw, roll and pitch within --max-tilt; yaw: level turns.",
)
@click.option(
    "--max-tilt",
    type=click.FloatRange(min=0, max=180),
    default=20.0,
    show_default=True,
    help="Roll and pitch limit of --orientations restricted, degrees.",
)
@click.option(
    "--truth",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Also write the true calibration as JSON (as 'magfit calibrate -o' would).",
)
@click.option("--force", is_flag=True, help="Overwrite OUTPUT (and --truth) if they exist.")
def simulate_command(
    sensor: str,
    disturbance: str,
    n_samples: int,
    output: Path,
    seed: int | None,
    offset: list[float] | None,
    matrix: list[float] | None,
    noise: float | None,
    field_strength: float | None,
    orientations: str,
    max_tilt: float,
    truth: Path | None,
    force: bool,
) -> None:
    """Simulate magnetometer samples of the paper's model, with a known calibration.

    B_p = W R B (cos δ, 0, sin δ) + V (paper, eq. 1). The sensor and disturbance pick W, V, B and the
    noise of the paper's scenario; --offset, --matrix, --noise and --field-strength override them one
    by one (with --field-strength the samples are not rounded to whole counts). The true calibration
    is printed (and written with --truth).

    \b
    Examples:
      magfit simulate --sensor mpu9250 --disturbance steel -n 5000 -o steel.csv --seed 1
      magfit simulate -n 2000 -o ring.csv --orientations yaw
      magfit simulate -n 3000 -o custom.npy --offset=-30,12,45 --matrix 1.1,0,0,0,0.9,0,0,0,1 --noise 0.5 \\
          --field-strength 50 --truth custom_truth.json
    """
    suffix = output.suffix.lower()
    if suffix not in CSV_EXTENSIONS + NPY_EXTENSIONS:
        fail(f"cannot tell the format of {output}: use a .csv, .txt or .npy extension")
    targets = [output] + ([truth] if truth is not None else [])
    if truth is not None:
        refuse_overwriting_input(truth, [output])
    existing = [str(path) for path in targets if path.exists()]
    if existing and not force:
        fail(f"{', '.join(existing)} already exists; pass --force to overwrite")
    from ..io import check_output

    for path in targets:  # before anything is written: a failed run must leave both files as they were
        check_output(path)

    simulation = _simulate(
        sensor, disturbance, n_samples, seed, offset, matrix, noise, field_strength, orientations, max_tilt
    )
    write_samples(output, simulation.samples)
    if truth is not None:
        from ..io import atomic_write_text

        atomic_write_text(truth, simulation.truth.to_json() + "\n")
    out = console()
    cal = simulation.truth
    out.print(f"wrote {n_samples} samples to {output} ({sensor}, {disturbance}, {orientations} orientations)")
    out.print(f"true offset     {vector(cal.offset, lambda v: significant(v, 6))}")
    out.print(f"true semi-axes  {vector(cal.semi_axes, lambda v: significant(v, 6))}")
    out.print(f"true field B    {significant(cal.field_strength, 6)}")
    if truth is not None:
        out.print(f"wrote the true calibration to {truth}")


def _simulate(
    sensor: str,
    disturbance: str,
    n_samples: int,
    seed: int | None,
    offset: list[float] | None,
    matrix: list[float] | None,
    noise: float | None,
    field_strength: float | None,
    orientations: str,
    max_tilt: float,
) -> Simulation:
    """The scenario of ``sensor`` and ``disturbance``, with each given parameter overriding its own."""
    base = scenario(sensor, disturbance)
    soft_iron = base.soft_iron if matrix is None else np.reshape(matrix, (3, 3))
    given = ",".join(f"{value:g}" for value in matrix) if matrix is not None else ""
    if matrix is not None and abs(np.linalg.det(soft_iron)) < 1e-12:
        raise OptionError(f"--matrix {given} is singular: the soft iron W must be invertible; give nine numbers "
                          "row by row whose determinant is not zero")  # fmt: skip
    if matrix is not None and np.linalg.det(soft_iron) < 0:
        raise OptionError(f"--matrix {given} is a mirror (negative determinant): soft iron never turns a sensor's "
                          "axes left-handed; negate a row to simulate a sensor wired so")  # fmt: skip
    return simulate(
        n_samples,
        soft_iron=soft_iron,
        hard_iron=base.hard_iron if offset is None else offset,
        field_strength=base.field_strength if field_strength is None else field_strength,
        inclination_deg=base.inclination_deg,
        noise=base.noise if noise is None else noise,
        orientations=orientations,
        max_tilt_deg=max_tilt,
        # Quantisation to whole counts belongs to the sensor's own scale, not to a field given in other units.
        resolution=base.resolution if field_strength is None else None,
        seed=seed,
    )
