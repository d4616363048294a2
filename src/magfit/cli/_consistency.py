"""``magfit calibrate``'s checks of a log (the firmware's acceptance tests replayed, the compasses against each
other) and ``magfit inspect``'s quick look (the firmware's own reports, the compasses' rotation).

The work is :mod:`magfit.consistency`; this module only words it: one labelled line per fact, the findings with
their codes, the remedy as the parameter to set.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..consistency import ARDUPILOT_LIMITS, PX4_ANGLE_LIMIT_DEG, CompassComparison, CompassField, compare_fields
from ..rotations import polar_decomposition
from ._common import console, one_line

if TYPE_CHECKING:
    from ..firmware_checks import LogExplanation
    from ..pipeline import FileCalibration
    from ..sources import Source
    from ..sources.calibration_messages import CalibrationMessages

#: What a check may raise on a damaged or unusual log: said in one line, the calibrations above stand.
_CHECK_ERRORS = (ValueError, ArithmeticError, IndexError, KeyError, OSError, np.linalg.LinAlgError)
#: ``magfit inspect`` fits each compass's sphere on at most this many samples (an even stride of the log).
INSPECT_SAMPLES = 20_000


def _basis(basis: str) -> str:
    return "headings, level with the motors off" if basis == "level" else "log's stamps"


def comparison_lines(comparison: CompassComparison) -> list[tuple[str, str]]:
    """The labelled lines that say what :func:`magfit.consistency.compare_fields` found."""
    lines: list[tuple[str, str]] = []
    for index, pair in enumerate(comparison.pairs):
        sigma = f" ± {pair.sigma_deg:.1f}°" if np.isfinite(pair.sigma_deg) else ""
        axis = ", ".join(f"{v:+.2f}" for v in pair.axis)
        undetermined = "" if pair.determined else " (not determined about every axis)"
        text = (
            f"{pair.second} is turned {pair.angle_deg:.1f}°{sigma} from {pair.first} (axis {axis}), "
            f"{pair.n_samples} common stamps, residual {pair.residual_rms:.3g} {comparison.unit}{undetermined}"
        )
        lines.append(("compasses" if index == 0 else "", text))
        if pair.current is not None and pair.current.r_squared >= 0.05:
            c = pair.current
            who = f": {', '.join(c.follower)} follows it" if c.follower else ""
            lines.append(
                (
                    "",
                    f"their difference follows the {c.regressor} ({c.source}): R² {c.r_squared:.2f}, "
                    f"{c.at_full_pct:.1f} % of the field at the highest {c.regressor}{who}",
                )
            )
    firmware = comparison.firmware
    if firmware in (None, "ardupilot"):
        limits = ARDUPILOT_LIMITS
        for ap in comparison.ardupilot:
            length = f", horizontal difference {ap.xy_length:.0f} mG" if np.isfinite(ap.xy_length) else ""
            verdict = f"FAILS ({'; '.join(ap.failing)})" if ap.failing else "passes at the median"
            if not ap.checked:
                verdict = "not checked by the firmware (not used for yaw: COMPASS_USEn 0)"
            lines.append(
                (
                    "ArduPilot check",
                    f"{ap.sensor} against {ap.primary}: 3-D {ap.xyz_angle_deg:.0f}°, horizontal {ap.xy_angle_deg:.0f}°"
                    f"{length} (limits {limits[0]:.0f}°, {limits[1]:.0f}°, {limits[2]:.0f} mG): {verdict}; fails at "
                    f"{100 * ap.fail_share:.0f} % of the {_basis(ap.basis)}",
                )
            )
    if firmware in (None, "px4"):
        for px in comparison.px4:
            verdict = "FAILS" if px.fail_share > 0.5 else "passes" if px.fail_share == 0 else "fails at some headings"
            lines.append(
                (
                    "PX4 check",
                    f"{px.sensor} against {px.primary}: {px.angle_deg:.0f}° (filtered, at most "
                    f"{px.filtered_max_deg:.0f}°; COM_ARM_MAG_ANG {PX4_ANGLE_LIMIT_DEG:.0f}°): {verdict}",
                )
            )
    for reason in comparison.findings:
        fix = "; set " + ", ".join(f"{name} {value}" for name, value in reason.remedy) if reason.remedy else ""
        lines.append(("finding", f"[{reason.code}] {reason}{fix}"))
    lines.append(("prefer", _priority_text(comparison)))
    return lines


def _priority_text(comparison: CompassComparison) -> str:
    now = _order_text(comparison, comparison.priority)
    if not comparison.priority_fixed or comparison.priority_fixed == comparison.priority:
        return now
    fix = next(r for r in comparison.findings if r.code == "compass_misoriented" and r.remedy)
    setting = ", ".join(f"{name} {value}" for name, value in fix.remedy)
    return f"{now} as mounted now; once {setting} is set: {_order_text(comparison, comparison.priority_fixed)}"


def _order_text(comparison: CompassComparison, priority: tuple[str, ...]) -> str:
    order = ", ".join(priority)
    ids = dict(zip(comparison.compasses, comparison.device_ids, strict=False))
    slots = dict(zip(comparison.compasses, comparison.slots, strict=False))
    if comparison.firmware == "ardupilot" and all(ids.get(name) is not None for name in priority):
        params = ", ".join(f"COMPASS_PRIO{k + 1}_ID {ids[name]}" for k, name in enumerate(priority))
        return f"{order} ({params})"
    if comparison.firmware == "px4" and all(slots.get(name) is not None for name in priority):
        params = ", ".join(
            f"CAL_MAG{slots[name]}_PRIO {value}" for name, value in zip(priority, (100, 75, 50), strict=False)
        )
        return f"{order} ({params})"
    return order


def replay_lines(explanation: LogExplanation) -> list[tuple[str, str]]:
    """One line per compass and firmware: what its acceptance tests would report, and the first failure's reason;
    then what the log's firmware itself said about its calibration."""
    lines: list[tuple[str, str]] = []
    for replay in explanation.replays:
        label = "ArduPilot tests" if replay.firmware == "ardupilot" else "PX4 tests"
        shown = [t for t in replay.tests if t.passed is not None]
        figures = "; ".join(
            f"{t.name} {t.value}" + (f": {t.margin}" if t.name == "orientation" and t.margin else "")
            for t in shown
            if t.name in ("fitness", "radius", "orientation")
        )
        if replay.status == "unknown":
            lines.append((label, f"{replay.sensor}: not replayed ({replay.tests[-1].value})"))
        elif replay.passed:
            lines.append((label, f"{replay.sensor}: {replay.status} ({figures})"))
        else:
            lines.append((label, f"{replay.sensor}: would report {replay.status} ({figures})"))
            for reason in replay.reasons:
                fix = "; set " + ", ".join(f"{n} {v}" for n, v in reason.remedy) if reason.remedy else ""
                lines.append(("", f"[{reason.code}] {reason}{fix}"))
    lines += [("", f"({note})") for note in explanation.notes if explanation.replays]
    lines += said_lines(explanation.said)
    return lines


def said_lines(said: CalibrationMessages | None) -> list[tuple[str, str]]:
    """The firmware's own calibration reports and messages found in a log."""
    if said is None:
        return []
    lines: list[tuple[str, str]] = []
    for report in said.reports:
        lines.append(
            (
                "firmware said",
                f"MAG_CAL_REPORT compass {report.compass_id}: {report.status}, fitness {report.fitness:.1f} mG, "
                f"offsets ({', '.join(f'{v:.0f}' for v in report.offsets)}) mG",
            )
        )
    for message in said.messages[:10]:
        lines.append(("firmware said" if not lines else "", message.text))
    if len(said.messages) > 10:
        lines.append(("", f"... and {len(said.messages) - 10} more lines about the compass"))
    return lines


def temperature_lines(result: FileCalibration) -> list[tuple[str, str]]:
    """The offset's drift per °C of each compass whose temperature the log has (PX4 ``sensor_mag``)."""
    from ..temperature import log_drifts

    try:
        drifts = log_drifts(result)
    except _CHECK_ERRORS as error:
        return [("temperature", f"not read: {one_line(str(error))}")]
    lines: list[tuple[str, str]] = []
    for sensor, drift in drifts.items():
        span = f"{drift.range_c[0]:.1f} to {drift.range_c[1]:.1f} °C"
        if drift.determined:
            values = ", ".join(f"{d:+.3g} ± {s:.2g}" for d, s in zip(drift.drift, drift.sigma, strict=True))
            text = f"{sensor}: {span}; offset drift ({values}) {drift.unit}/°C (x, y, z, sensor axes)"
        else:
            text = f"{sensor}: {span}; no drift determined: {drift.reasons[0]}"
        lines.append(("temperature" if not lines else "", text))
    return lines


def print_log_checks(result: FileCalibration, *, stderr: bool = False) -> None:
    """``magfit calibrate``'s blocks on a log: the firmware's acceptance tests replayed on each compass, and, with
    two or more compasses fitted, the compasses against each other. A line saying why when a check cannot run;
    never raises a magfit error (the calibrations above stand without these checks)."""
    if not any(compass.magnetometer is not None for compass in result.compasses):
        return
    from ..consistency import compare_compasses
    from ..firmware_checks import explain_log

    out = console(stderr=stderr)
    out.print("")
    try:
        lines = replay_lines(explain_log(result))
    except _CHECK_ERRORS as error:
        lines = [("firmware tests", f"not replayed: {one_line(str(error))}")]
    lines += temperature_lines(result)
    if len(result.compasses) >= 2:
        try:
            lines += comparison_lines(compare_compasses(result))
        except _CHECK_ERRORS as error:
            lines.append(("compasses", f"not compared: {one_line(str(error))}"))
    for label, text in lines:
        out.print(f"{label:<16} {text}", soft_wrap=True)


def inspect_lines(source: Source) -> list[tuple[str, str]]:
    """``magfit inspect``'s quick look at a log's compasses against each other: each compass's sphere fit (offsets
    only, on an even stride of at most :data:`INSPECT_SAMPLES`), then their rotation. Empty for fewer than two
    usable compasses; one line saying why when they cannot be compared."""
    import magfit

    from ..sources.calibration_messages import read_calibration_messages

    if source.kind == "samples":
        return []
    try:
        said = said_lines(read_calibration_messages(source.path))
    except _CHECK_ERRORS:
        said = []
    usable = [m for m in source.magnetometers if m.problem is None and m.n_samples > 0]
    if len(usable) < 2:
        return said
    firmware = {"dataflash": "ardupilot", "tlog": "ardupilot", "mavlogdump": "ardupilot", "ulog": "px4"}.get(
        source.kind
    )
    fields = []
    crude: list[str] = []
    try:
        for magnetometer in usable:
            read = source.read(magnetometer.id)
            stride = max(1, len(read.samples) // INSPECT_SAMPLES)
            samples, time_s = read.samples[::stride], read.time_s[::stride]
            try:  # the soft iron turns the field by a few degrees: the ellipsoid when the samples determine it
                fit = magfit.fit(samples, method="ellipsoid", allow_undetermined=True)
            except _CHECK_ERRORS:
                fit = magfit.fit(samples, method="sphere", allow_undetermined=True)
                crude.append(magnetometer.id)
            _, symmetric = polar_decomposition(fit.matrix)
            fields.append(
                CompassField(
                    magnetometer.id, time_s, (samples - fit.offset) @ symmetric.T, magnetometer.unit, None, None,
                    magnetometer.slot, magnetometer.device_id, firmware,
                )
            )  # fmt: skip
        comparison = compare_fields(fields)
    except _CHECK_ERRORS as error:
        return [*said, ("compasses", f"not compared: {one_line(str(error))}")]
    lines = [
        (label, text)
        for label, text in comparison_lines(comparison)
        if label in ("compasses", "") and "follows the" not in text
    ]
    how = "a quick ellipsoid fit of each"
    if crude:
        how = f"hard iron only for {', '.join(crude)} (its soft iron can turn it by a few degrees more than stated)"
    lines.append(("", f"({how}, frames as logged: 'magfit calibrate' gives the full check)"))
    return said + lines
