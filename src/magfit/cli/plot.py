"""``magfit plot``: one PNG that shows a recording before and after calibration, for each method."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import click
from numpy.typing import ArrayLike

from ..compare import PAPER_METHODS, Comparison, compare
from ..errors import CalibrationError
from ..plot import method_labels
from ._common import (
    RegistryChoice,
    console,
    default_method,
    fixed,
    method_names,
    nonfinite_option,
    parse_columns,
    refuse_overwriting_input,
    warn,
)
from ._extras import require
from ._logs import read_recordings, sensor_option, with_streams
from ._wording import columns_used
from .compare import parse_methods

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Figure formats ``-o`` accepts (matplotlib's Agg canvas writes them all).
FIGURE_EXTENSIONS = (".png", ".svg", ".pdf")


def methods_in_order(main: str, others: Sequence[str]) -> tuple[str, ...]:
    """The main method first, then the others in their order, each once."""
    return (main, *(name for name in others if name != main))


def fit_for_plot(
    samples: ArrayLike,
    methods: Sequence[str],
    path: Path,
    columns: str = "",
    streams: Mapping[str, Any] | None = None,
) -> Comparison:
    """Compare ``methods`` on ``samples`` (with the ``streams`` vector and gyro need); warn about each failed
    method, raise when the main one failed.

    ``columns`` (``"columns mx, my, mz"``) is named in the refusal: which columns could not be fitted.
    """
    # The other methods are drawn even when the samples do not support them (the paper's figures compare
    # all three), labelled so; the main one must be supported.
    comparison = compare(samples, methods, allow_undetermined=True, streams=streams)
    main = comparison.results[0]
    where = f"{path} ({columns})" if columns else str(path)
    if not main.ok:
        raise CalibrationError(f"{where}: the {main.method} fit failed, nothing to plot: {main.error}")
    diagnostics = main.calibration.diagnostics if main.calibration is not None else None
    if diagnostics is not None and diagnostics.support is not None and diagnostics.support.verdict == "refused":
        reason = diagnostics.support.message(main.method)
        raise CalibrationError(f"{where}: nothing to plot: {reason}; draw it with another --method")
    for result in comparison.results[1:]:
        if not result.ok:
            warn(f"{path}: {result.method} could not fit these samples and is left out of the plot: {result.error}")
    return comparison


def check_figure_path(output: Path, option: str = "'-o' / '--output'") -> None:
    """Refuse an output whose extension is not a figure format, before any work is done."""
    if output.suffix.lower() not in FIGURE_EXTENSIONS:
        raise click.BadParameter(
            f"{output.name!r} has no figure extension; use one of {', '.join(FIGURE_EXTENSIONS)}", param_hint=option
        )


@click.command("plot")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="The figure to write: .png (default size 1600 x 1200 pixels), .svg or .pdf.",
)
@click.option(
    "-m",
    "--method",
    type=RegistryChoice("method", method_names),
    default=None,
    help="The main method: its ellipsoid, calibrated samples and coverage map are drawn "
    "(default: auto when available, else ellipsoid).",
)
@click.option(
    "--methods",
    callback=parse_methods,
    metavar="M,M,...",
    help="Methods compared in the projections and the histogram. Default: the paper's ellipsoid,sphere,minmax.",
)
@click.option(
    "--columns",
    callback=parse_columns,
    metavar="X,Y,Z",
    help="The three magnetometer columns: names (mx,my,mz) or 0-based numbers (3,4,5). Default: detected.",
)
@click.option("--unit", help="Name of the input unit for the axis labels (uT, mG, counts ...).")
@click.option("--title", help="What the data are, leading the figure title. Default: the file name.")
@click.option(
    "--max-points",
    type=click.IntRange(min=100),
    default=4000,
    show_default=True,
    help="Samples drawn per scatter panel; longer recordings are subsampled evenly over directions.",
)
@click.option("--dpi", type=click.IntRange(min=20, max=600), default=100, show_default=True, help="Pixels per inch.")
@nonfinite_option
@sensor_option
def plot_command(
    file: Path,
    output: Path,
    method: str | None,
    methods: tuple[str, ...],
    columns: list[str | int] | None,
    unit: str | None,
    title: str | None,
    max_points: int,
    dpi: int,
    nonfinite: Literal["skip", "error"],
    sensor: str | None,
) -> None:
    """Draw a recording before and after calibration, in one figure.

    Panels: the raw samples with the fitted ellipsoid and the calibrated samples on the unit sphere (3-D),
    a map of the directions visited, the XY, XZ and YZ projections before and after, the distance to the
    unit sphere for each method (the paper's metric) and a table of the fitted parameters. The title gives
    the field strength and each method's mean and std of the distance to the unit sphere.

    \b
    Examples:
      magfit plot mag-readings.txt -o mag.png --unit uT
      magfit plot flight.csv --columns mx,my,mz --method ellipsoid --methods sphere,minmax -o flight.png
      magfit plot 00000042.BIN --sensor MAG/1 -o compass2.png

    FILE may be a flight log or bag (ULog, DataFlash, ROS): --sensor chooses its compass.
    """
    from ..io import check_output, write_all
    from ..plot import calibration_figure

    require("plot", "magfit plot", ("matplotlib",))
    check_figure_path(output)
    refuse_overwriting_input(output, [file])
    check_output(output)
    (recording,) = read_recordings(file, columns=columns, nonfinite=nonfinite, sensor=sensor, every=False)
    used = columns_used(recording.columns, recording.column_note)
    drawn = methods_in_order(method or default_method(), methods or PAPER_METHODS)
    # vector and gyro take the file's own streams (found by name, as calibrate and compare find them)
    samples, streams = with_streams(recording, drawn, unit, path=file, columns=columns, nonfinite=nonfinite)
    comparison = fit_for_plot(samples, drawn, file, used, streams)
    calibrations = [result.calibration for result in comparison if result.calibration is not None]
    figure = calibration_figure(
        samples,
        calibrations,
        unit=unit or recording.unit,
        title=title or recording.name,
        max_points=max_points,
        dpi=dpi,
    )
    write_all([(output, figure_bytes(figure, output))])  # atomic: a failed save leaves an existing figure as it was
    out = console()
    out.print(f"{file}{f' ({recording.sensor})' if recording.sensor else ''}: {used}", soft_wrap=True)
    for result in comparison:
        if result.evaluation is not None and result.calibration is not None:
            (label,) = method_labels([result.calibration])  # "sphere (not supported)" as in the figure
            out.print(
                f"{label:<12} sphere distance mean {fixed(result.evaluation.mean)}  std {fixed(result.evaluation.std)}",
                soft_wrap=True,
            )
    out.print(f"{figure.get_supxlabel()} Wrote the figure to {output}", soft_wrap=True)


def figure_bytes(figure: Figure, output: Path) -> bytes:
    """The figure in the format of ``output``'s extension, to be written with the command's other outputs."""
    import io

    buffer = io.BytesIO()
    figure.savefig(buffer, format=output.suffix.lower().lstrip("."), dpi="figure")
    return buffer.getvalue()
