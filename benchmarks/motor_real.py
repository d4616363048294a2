"""The motors' field on real flight logs: magfit against pymavlink's ``magfit_WMM.py --cmot`` and a plain regression.

Every calibration is scored on the same samples (the firmware's calibration undone, as magfit reads the log)
by the residual against the World Magnetic Model's field (magfit's WMM at the log's GNSS position and date)
turned into the body frame by the log's attitude (``ATT``, the trim taken off as both tools do), in three ways:

- ``att``: ``|corrected − Aᵀ B|`` with the logged attitude ``A`` whole (roll, pitch and the EKF's yaw);
- ``rp``: the same with the yaw recomputed from the corrected compass (magfit_WMM's own objective: only roll
  and pitch are taken from the log), which in closed form is ``(|h_c| − |h_B|)² + (z_c − z_B)²`` of the level
  frame's horizontal and vertical parts;
- ``|B|``: ``|corrected| − |B|`` (what a fit from the magnitude alone, like magfit's, minimises).

Each calibration is applied as the firmware would apply it: through its ArduPilot parameters and
``AP_Compass_Backend::correct_field`` (re-implemented in benchmarks/motor.py), with the current the firmware
sees at the sample (the last value logged before it, no lag). The rows:

- ``as flown``: the log's own COMPASS_* parameters (no motor term: COMPASS_MOTCT 0);
- ``magfit --motor none|auto|current``: ``magfit.calibrate_file`` with the WMM field strength at the log;
- ``plain regression``: ``raw − Aᵀ B = V + k c`` by linear least squares (offset and current slope per axis,
  no soft iron, the logged attitude taken as true);
- ``magfit_WMM --cmot``: pymavlink's tool (run in a subprocess by the interpreter ``--pymavlink-python`` names,
  skipped when it cannot import pymavlink). It reads the current from ``BAT.Curr`` only; a log that logs
  ``CURR.Curr`` (ArduCopter 3.3 and older, centiamperes in an int16) is given to it as a copy whose CURR format
  is renamed BAT with the field's letter ``c`` (int16 × 0.01), so it reads amperes; nothing else changes.
  A log without ``AHRS_EKF_TYPE`` is given ``--att-source ATT`` (it raises KeyError otherwise).

Run: ``PYTHONPATH=src python benchmarks/motor_real.py LOG [LOG ...] --pymavlink-python /tmp/pmv/bin/python``
(writes benchmarks/results/motor_real.md). ``--wmm-params DIR`` reuses ``.param`` files a previous run saved.
"""

from __future__ import annotations

import argparse
import datetime
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import magfit
from magfit.calibration import Calibration
from magfit.errors import MagfitError
from magfit.export import export
from magfit.geomag import field_at
from magfit.sources import open_source
from magfit.sources.dataflash import DataFlashLog
from magfit.sources.power import read_power

sys.path.insert(0, str(Path(__file__).parent))
from motor import _params_ardupilot, ardupilot_correct

RESULTS = Path(__file__).parent / "results" / "motor_real.md"
#: magfit's rows of the held-out tests (method, motor): the default, no term, and the vector method.
HELD_OUT_METHODS = (
    ("auto", "none"),
    ("auto", "auto"),
    ("vector", "auto"),
    ("tilt", "none"),
    ("tilt", "current"),
    ("tilt!", "current"),
)
#: The DataFlash FMT message: header (3), type (1), length (1), name (4), format letters (16), labels (64).
FMT_HEADER, FMT_SIZE = b"\xa3\x95\x80", 89


@dataclass
class Flight:
    """One compass of a log, with what every score needs."""

    sensor: str
    raw: np.ndarray
    attitude: np.ndarray
    field_ned: np.ndarray
    current: np.ndarray
    params: dict[str, float]
    index: int
    time_s: np.ndarray | None = None

    def subset(self, keep: np.ndarray) -> Flight:
        """The samples ``keep`` selects."""
        time_s = None if self.time_s is None else self.time_s[keep]
        return Flight(self.sensor, self.raw[keep], self.attitude[keep], self.field_ned, self.current[keep],
                      self.params, self.index, time_s)  # fmt: skip


def scores(corrected: np.ndarray, flight: Flight) -> list[float]:
    """RMS residuals (mG) over every sample: against the field turned by the whole attitude, with the yaw
    recomputed, of the magnitude; then the last two over the upright samples only (tilt below 90°)."""
    up = flight.attitude[:, 2, 2] > 0
    return [*_scores(corrected, flight), *_scores(corrected[up], flight.subset(up))[1:]]


def _scores(corrected: np.ndarray, flight: Flight) -> tuple[float, float, float]:
    expected = np.einsum("nji,j->ni", flight.attitude, flight.field_ned)
    att = float(np.sqrt(np.mean(np.sum((corrected - expected) ** 2, axis=1))))
    # Level frame without the yaw: the attitude's yaw taken off (A = Rz(ψ) Ry Rx, so Rz(-ψ) A is roll and pitch).
    ned = np.einsum("nij,nj->ni", flight.attitude, corrected)
    h_c, z_c = np.hypot(ned[:, 0], ned[:, 1]), ned[:, 2]
    h_b, z_b = np.hypot(*flight.field_ned[:2]), flight.field_ned[2]
    rp = float(np.sqrt(np.mean((h_c - h_b) ** 2 + (z_c - z_b) ** 2)))
    mag = float(np.sqrt(np.mean((np.linalg.norm(corrected, axis=1) - np.linalg.norm(flight.field_ned)) ** 2)))
    return att, rp, mag


def _held(signal_t: np.ndarray, signal_v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The last value logged at or before each stamp (what the firmware's correction uses), the first before it."""
    i = np.clip(np.searchsorted(signal_t, t, side="right") - 1, 0, len(signal_v) - 1)
    return signal_v[i]


def _log_params(path: Path) -> dict[str, float]:
    table = DataFlashLog(path, path).parameters()
    return {name: values[-1][1] for name, values in table.items()}


def _as_compass_one(params: dict[str, float], index: int) -> dict[str, float]:
    """The log's parameters of compass ``index`` (1-based) under compass 1's names, as ardupilot_correct reads."""
    suffix = "" if index == 1 else str(index)
    out = {}
    for short in ("OFS", "DIA", "ODI", "MOT"):
        for axis in "XYZ":
            default = 1.0 if short == "DIA" else 0.0
            out[f"COMPASS_{short}_{axis}"] = params.get(f"COMPASS_{short}{suffix}_{axis}", default)
    if out["COMPASS_DIA_X"] == 0.0:  # never calibrated: the firmware uses the identity
        out.update({f"COMPASS_DIA_{a}": 1.0 for a in "XYZ"})
    out["COMPASS_SCALE"] = params.get(f"COMPASS_SCALE{suffix}", 1.0) or 1.0
    out["COMPASS_MOTCT"] = params.get("COMPASS_MOTCT", 0.0)
    return out


def flights(path: Path) -> tuple[list[Flight], str]:
    """The log's ArduPilot compasses with the current the firmware would see, and the WMM field at the log."""
    source = open_source(path)
    power = read_power(path)
    if power.current is None:
        raise SystemExit(f"{path}: no battery current logged; nothing to compare")
    params = _log_params(path)
    position = source.position
    if position is None:
        raise SystemExit(f"{path}: no GNSS fix logged; the WMM field needs the place")
    date = datetime.datetime.fromtimestamp(position.time_s, tz=datetime.timezone.utc).date()
    model = field_at(position.lat_deg, position.lon_deg, position.alt_km, date=date)
    field = np.array([model.north, model.east, model.down]) * 1e-2  # nT -> mG
    out = []
    for index, mag in enumerate(source.magnetometers, start=1):
        try:
            motion = source.read_motion(mag.id)
        except MagfitError:
            continue
        if motion.attitude is None:
            continue
        current = _held(power.current.time_s, power.current.values, motion.time_s)
        out.append(Flight(mag.id, motion.samples, motion.attitude, field, current, params, index, motion.time_s))
    where = f"{model.model} at {model.latitude:.3f}°, {model.longitude:.3f}°, {model.year:.2f}"
    return out, f"{where}: |B| {np.linalg.norm(field):.1f} mG, inclination {model.inclination_deg:.1f}°"


def magfit_rows(
    path: Path, flight: Flight, on: Flight | None = None, choices: tuple[tuple[str, str], ...] | None = None
) -> list[tuple[str, np.ndarray | None, str]]:
    """magfit's calibrations of ``path`` (``--motor`` and ``--method`` per ``choices``) applied to ``on``."""
    on = flight if on is None else on
    rows: list[tuple[str, np.ndarray | None, str]] = []
    choices = choices or (
        ("auto", "none"),
        ("auto", "auto"),
        ("auto", "current"),
        ("sphere", "auto"),
        ("vector", "auto"),
        ("tilt", "none"),
        ("tilt", "current"),
        ("tilt!", "none"),
        ("tilt!", "current"),
    )
    for method, motor in choices:
        start = time.perf_counter()
        name, calibration, refused = _calibrated(path, flight, method, motor)
        if calibration is None:
            rows.append((name, None, refused))
            continue
        seconds = time.perf_counter() - start
        params = _params_ardupilot(export(calibration, "ardupilot", slot=0))
        corrected = ardupilot_correct(params, on.raw, on.current, on.current)
        term = calibration.motor
        lag = f", lag {1000 * term.lag_s:.0f} ms" if term is not None else ""
        verdict = _verdict_words(calibration)
        rows.append((name, corrected, f"{_term_words(calibration, ' of the field')}{lag}; {verdict}; {seconds:.0f} s"))
    return rows


def _calibrated(path: Path, flight: Flight, method: str, motor: str) -> tuple[str, Calibration | None, str]:
    """magfit's calibration of ``flight``'s compass in ``path`` with ``method`` and ``--motor motor``, as the
    command line would run it: (its row's name, the calibration or None, the refusal's codes)."""
    forced = method.endswith("!")  # the method's answer when it refuses (allow_undetermined): what it would say
    method = method.rstrip("!")
    name = f"magfit --motor {motor}" + (f" --method {method}" if method != "auto" else "")
    name += " (forced)" if forced else ""
    options = {"allow_undetermined": True} if forced else None
    try:
        result = magfit.calibrate_file(path, method, sensor=flight.sensor, location="log", motor=motor, options=options,
                                       field_strength=None if method in ("vector", "tilt") else "wmm")  # fmt: skip
    except MagfitError as error:
        return name, None, f"refused ({', '.join(error.codes) or 'no code'})"
    return name, result.calibration, ""


def _verdict_words(calibration: Calibration) -> str:
    """The verdict, its codes and the heading one-sigma stated."""
    support = calibration.support
    if support is None:
        return "no verdict"
    codes = ", ".join(support.codes)
    diagnostics = calibration.diagnostics
    uncertainty = diagnostics.uncertainty if diagnostics is not None else None
    sigma = uncertainty.heading_sigma_deg if uncertainty is not None else None
    said = f"{support.verdict}" + (f" ({codes})" if codes else "")
    return said + (f", ±{sigma:.1f}°" if sigma is not None else "")


def _term_words(calibration: Calibration, share: str = "") -> str:
    """The motors' term a calibration keeps, in words: k, and its share of the field at full scale."""
    term = calibration.motor
    if term is None:
        return "no term"
    k = term.coefficients
    percent = 100 * term.at_full_scale() / calibration.field_strength
    return f"k ({k[0]:.2f}, {k[1]:.2f}, {k[2]:.2f}) mG/A, {percent:.1f} %{share} at {term.full_scale:.1f} A"


def plain_regression(flight: Flight, on: Flight | None = None) -> tuple[np.ndarray, str]:
    """``raw − Aᵀ B = V + k c`` per axis by least squares: the naive fit that takes the attitude as true
    (fitted on ``flight``, applied to ``on``, by default the same)."""
    offset, k, note = _regression(flight)
    return _apply(("regression", offset, k), flight if on is None else on), note


def _wmm_tool(python: str) -> Path | None:
    try:
        found = subprocess.run(
            [python, "-c", "import os, pymavlink; print(os.path.dirname(pymavlink.__file__))"],
            capture_output=True, text=True, timeout=60, check=True,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    tool = Path(found.stdout.strip()) / "tools" / "magfit_WMM.py"
    return tool if tool.is_file() else None


def _bat_copy(path: Path, into: Path) -> Path:
    """The log as magfit_WMM can read its current: CURR renamed BAT, Curr's letter h -> c (amperes)."""
    data = bytearray(path.read_bytes())
    if b"BAT\x00" in data or b"CURR" not in data:
        return path
    i, renamed = 0, 0
    while (i := data.find(FMT_HEADER, i)) >= 0:
        if bytes(data[i + 5 : i + 9]) == b"CURR":
            letters = bytes(data[i + 9 : i + 25]).rstrip(b"\x00").decode()
            labels = bytes(data[i + 25 : i + 89]).rstrip(b"\x00").decode().split(",")
            column = labels.index("Curr")
            if letters[column] == "h":
                data[i + 5 : i + 9] = b"BAT\x00"
                data[i + 9 + column] = ord("c")
                renamed += 1
        i += 1
    if renamed != 1:
        raise SystemExit(f"{path}: could not give magfit_WMM the current (CURR formats renamed: {renamed})")
    copy = into / (path.stem + "_bat.bin")
    copy.write_bytes(bytes(data))
    return copy


def magfit_wmm(
    path: Path, flight: Flight, python: str, saved: Path | None, options: tuple[str, ...] = ("--cmot",)
) -> tuple[dict[str, float] | None, str]:
    """magfit_WMM.py's parameters for this compass with ``options`` (compass 1's names), and a note."""
    name = f"{path.stem}-mag-{flight.index}{''.join(o.replace('--', '-') for o in options)}.param"
    if saved is not None and (saved / f"{name}.failed").is_file():
        return None, (saved / f"{name}.failed").read_text().strip()
    if saved is not None and (saved / name).is_file():
        text, seconds = (saved / name).read_text(), None
        took = [line.split()[-2] for line in text.splitlines() if line.startswith("# took")]
        seconds = float(took[0]) if took else None
    else:
        tool = _wmm_tool(python)
        if tool is None:
            return None, f"skipped: {python} cannot import pymavlink"
        with tempfile.TemporaryDirectory() as tmp:
            log = _bat_copy(path, Path(tmp))
            if log == path:
                log = Path(shutil.copy(path, Path(tmp) / path.name))
            command = [python, str(tool), *options, "--mag", str(flight.index), "--save-params", str(log)]
            if "AHRS_EKF_TYPE" not in flight.params:
                command[2:2] = ["--att-source", "ATT"]
            start = time.perf_counter()
            run = subprocess.run(command, capture_output=True, text=True, timeout=3600,
                                 env={"MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"})  # fmt: skip
            seconds = time.perf_counter() - start
            out = log.with_name(f"{log.stem}-magfit-mag-{flight.index}.param")
            if run.returncode != 0 or not out.is_file():
                said = [line.strip() for line in (run.stdout + run.stderr).splitlines() if line.strip()]
                failed = [line for line in said if "failed" in line.lower()] or said[-1:] or ["no output"]
                note = f"failed after {seconds:.0f} s: {failed[-1]}"
                if saved is not None:
                    saved.mkdir(parents=True, exist_ok=True)
                    (saved / f"{name}.failed").write_text(note + "\n")
                return None, note
            text = out.read_text()
            if saved is not None:
                saved.mkdir(parents=True, exist_ok=True)
                (saved / name).write_text(f"# took {seconds:.0f} s\n{text}")
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    values = {n: float(v) for n, v in rows}
    suffix = "" if flight.index == 1 else str(flight.index)
    params = {}
    for short in ("OFS", "DIA", "ODI", "MOT"):
        for axis in "XYZ":
            params[f"COMPASS_{short}_{axis}"] = values[f"COMPASS_{short}{suffix}_{axis}"]
    params["COMPASS_SCALE"] = values[f"COMPASS_SCALE{suffix}"]
    params["COMPASS_MOTCT"] = values["COMPASS_MOTCT"]
    mot = [params[f"COMPASS_MOT_{a}"] for a in "XYZ"]
    ofs = [params[f"COMPASS_OFS_{a}"] for a in "XYZ"]
    took = f"; {seconds:.0f} s" if seconds is not None else ""
    terms = f"OFS ({ofs[0]:.0f}, {ofs[1]:.0f}, {ofs[2]:.0f}), k ({mot[0]:.2f}, {mot[1]:.2f}, {mot[2]:.2f}) mG/A"
    return params, f"{terms}, scale {params['COMPASS_SCALE']:.3f}{took}"


def wmm_correct(params: dict[str, float], raw: np.ndarray, current: np.ndarray) -> np.ndarray:
    """magfit_WMM's own ``correct()``: as correct_field, but its scale factor applied whatever its value."""
    ofs = np.array([params[f"COMPASS_OFS_{a}"] for a in "XYZ"])
    dia, odi = [params[f"COMPASS_DIA_{a}"] for a in "XYZ"], [params[f"COMPASS_ODI_{a}"] for a in "XYZ"]
    mat = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    out = (params["COMPASS_SCALE"] * (raw + ofs)) @ mat.T
    return out + np.outer(current, [params[f"COMPASS_MOT_{a}"] for a in "XYZ"])


def truncated(path: Path, cut_s: float, into: Path) -> Path:
    """The log up to its first MAG record stamped after ``cut_s`` (every message before it, bytes unchanged)."""
    data = path.read_bytes()
    start = _first_mag_after(_messages(data), cut_s, path)
    out = into / f"{path.stem}_to{cut_s:.0f}s.bin"
    out.write_bytes(data[:start])
    return out


def _first_mag_after(messages: list[tuple[int, int, str, float | None]], cut_s: float, path: Path) -> int:
    """Where the first MAG record stamped after ``cut_s`` starts."""
    start = next((i for i, _, name, t in messages if name == "MAG" and t is not None and t > cut_s), None)
    if start is None:
        raise SystemExit(f"{path}: no MAG record after {cut_s} s")
    return start


#: Messages kept from before the cut when a log's head is dropped: what every reader needs to parse the rest.
KEPT_BEFORE = frozenset({"FMT", "FMTU", "UNIT", "MULT", "PARM", "MSG"})


def _messages(data: bytes) -> list[tuple[int, int, str, float | None]]:
    """Every DataFlash message: (start, length, name, time in s when its first field is a time stamp)."""
    formats: dict[int, tuple[int, str, str]] = {}
    out: list[tuple[int, int, str, float | None]] = []
    i = 0
    while i + 3 <= len(data):
        if data[i : i + 2] != FMT_HEADER[:2]:
            i += 1
            continue
        kind = data[i + 2]
        if kind == FMT_HEADER[2]:
            type_id, length = data[i + 3], data[i + 4]
            name = data[i + 5 : i + 9].rstrip(b"\x00").decode()
            letters = data[i + 9 : i + 25].rstrip(b"\x00").decode()
            formats[type_id] = (length, name, letters)
            out.append((i, FMT_SIZE, "FMT", None))
            i += FMT_SIZE
            continue
        if kind not in formats:
            i += 1
            continue
        length, name, letters = formats[kind]
        stamp = None
        if letters[:1] in ("I", "Q") and name not in KEPT_BEFORE:
            size = 4 if letters[0] == "I" else 8
            stamp = int.from_bytes(data[i + 3 : i + 3 + size], "little") * (1e-3 if size == 4 else 1e-6)
        out.append((i, length, name, stamp))
        i += length
    return out


def tail_from(path: Path, cut_s: float, into: Path) -> Path:
    """The log from its first MAG record stamped after ``cut_s``, with the formats, units and parameters
    logged before it (bytes unchanged): the reverse of :func:`truncated`."""
    data = path.read_bytes()
    messages = _messages(data)
    start = _first_mag_after(messages, cut_s, path)
    head = b"".join(data[i : i + n] for i, n, name, _ in messages if i < start and name in KEPT_BEFORE)
    out = into / f"{path.stem}_from{cut_s:.0f}s.bin"
    out.write_bytes(head + data[start:])
    return out


@dataclass(frozen=True)
class Split:
    """One held-out test: fit on one part of the log, score on the other (``head`` fits on the samples up to
    ``fraction`` of the compass's time span; otherwise on the samples from ``1 − fraction`` on)."""

    head: bool
    fraction: float = 0.7

    def cut_s(self, time_s: np.ndarray) -> float:
        share = self.fraction if self.head else 1.0 - self.fraction
        return float(time_s[0] + share * (time_s[-1] - time_s[0]))

    def words(self, time_s: np.ndarray) -> str:
        cut = self.cut_s(time_s)
        percent = round(100 * self.fraction)
        if self.head:
            return f"fitted on the first {percent} % (to {cut:.0f} s), scored on the rest"
        return f"fitted on the last {percent} % (from {cut:.0f} s), scored on the first {100 - percent} %"


def holdout(
    path: Path, flight: Flight, split: Split, python: str, saved: Path | None, methods: tuple[tuple[str, str], ...]
) -> list[str]:
    """Each calibration fitted on one part of the log (:class:`Split`) and scored on the upright samples of the
    other part (held out) and of its own part (in sample)."""
    assert flight.time_s is not None
    cut = split.cut_s(flight.time_s)
    fitted = flight.time_s <= cut if split.head else flight.time_s >= cut
    upright = flight.attitude[:, 2, 2] > 0
    train, test, own = flight.subset(fitted), flight.subset(~fitted & upright), flight.subset(fitted & upright)
    with tempfile.TemporaryDirectory() as tmp:
        part = truncated(path, cut, Path(tmp)) if split.head else tail_from(path, cut, Path(tmp))
        rows = [(name, fit, note) for name, fit, note in _fitted(part, flight, methods)]
        offset, k, note = _regression(train)
        rows.append(("plain regression (offset + k c)", ("regression", offset, k), note))
        for options in (("--cmot",), ("--cmot", "--elliptical")):
            params, note = magfit_wmm(part, flight, python, saved, options)
            rows.append((f"magfit_WMM {' '.join(options)}", None if params is None else ("wmm", params), note))
    lines = []
    for name, fit, note in rows:
        if fit is None:
            figures = "- | - | - | - | -"
        else:
            inside = _scores(_apply(fit, own), own)[1:]
            outside = _scores(_apply(fit, test), test)
            figures = " | ".join(f"{v:.1f}" for v in (*inside, *outside))
        lines.append(f"| {flight.sensor} | {name} | {figures} | {note} |")
        print(lines[-1], flush=True)
    return lines


def _fitted(path: Path, flight: Flight, methods: tuple[tuple[str, str], ...]) -> list[tuple[str, object, str]]:
    """magfit's calibrations of ``path`` as ArduPilot parameters (to be applied to any samples), with notes."""
    out: list[tuple[str, object, str]] = []
    for method, motor in methods:
        name, calibration, refused = _calibrated(path, flight, method, motor)
        if calibration is None:
            out.append((name, None, refused))
            continue
        note = f"{_term_words(calibration)}; {_verdict_words(calibration)}"
        out.append((name, ("ardupilot", _params_ardupilot(export(calibration, "ardupilot", slot=0))), note))
    return out


def _regression(flight: Flight) -> tuple[np.ndarray, np.ndarray, str]:
    expected = np.einsum("nji,j->ni", flight.attitude, flight.field_ned)
    design = np.column_stack([np.ones(len(flight.raw)), flight.current])
    coef, *_ = np.linalg.lstsq(design, flight.raw - expected, rcond=None)
    offset, k = coef[0], coef[1]
    note = f"offset ({offset[0]:.0f}, {offset[1]:.0f}, {offset[2]:.0f}) mG, k ({k[0]:.2f}, {k[1]:.2f}, {k[2]:.2f}) mG/A"
    return offset, k, note


def _apply(fit: object, on: Flight) -> np.ndarray:
    """A fitted calibration applied to ``on`` as its firmware (or magfit_WMM) would."""
    kind, *values = fit  # type: ignore[misc]
    if kind == "ardupilot":
        return ardupilot_correct(values[0], on.raw, on.current, on.current)
    if kind == "wmm":
        return wmm_correct(values[0], on.raw, on.current)
    offset, k = values
    return on.raw - offset - np.outer(on.current, k)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--pymavlink-python", default=sys.executable)
    parser.add_argument("--wmm-params", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--holdout", action="store_true",
                        help="also fit on the first 70 %% and score on the rest, and the reverse")  # fmt: skip
    parser.add_argument("--holdout-compasses", type=int, default=2, metavar="N",
                        help="the held-out tests for the first N compasses (default 2)")  # fmt: skip
    args = parser.parse_args(argv)
    lines = []
    for path in args.logs:
        found, where = flights(path)
        current = found[0].current if found else np.zeros(1)
        lines += [f"## `{path.name}`", "", f"Field: {where}. Current {current.min():.1f}-{current.max():.1f} A.", "",
                  "| compass | calibration | att | rp | \\|B\\| | rp upright | \\|B\\| upright | term and notes |",
                  "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for flight in found:
            rows: list[tuple[str, np.ndarray | None, str]] = []
            flown = ardupilot_correct(_as_compass_one(flight.params, flight.index), flight.raw, flight.current,
                                      flight.current)  # fmt: skip
            rows.append(
                ("as flown (the log's COMPASS_*)", flown, f"COMPASS_MOTCT {flight.params.get('COMPASS_MOTCT', 0):.0f}")
            )
            rows += magfit_rows(path, flight)
            rows.append(("plain regression (offset + k c)", *plain_regression(flight)))
            for options in (("--cmot",), ("--cmot", "--elliptical")):
                params, note = magfit_wmm(path, flight, args.pymavlink_python, args.wmm_params, options)
                corrected = None if params is None else wmm_correct(params, flight.raw, flight.current)
                rows.append((f"magfit_WMM {' '.join(options)}", corrected, note))
            for name, corrected, note in rows:
                figures = (
                    " | ".join(f"{v:.1f}" for v in scores(corrected, flight))
                    if corrected is not None
                    else "- | - | - | - | -"
                )
                line = f"| {flight.sensor} | {name} | {figures} | {note} |"
                print(line, flush=True)
                lines.append(line)
        lines.append("")
        if args.holdout and found:
            for flight in found[: args.holdout_compasses]:
                assert flight.time_s is not None
                for split in (Split(head=True), Split(head=False)):
                    lines += [f"Held out, {flight.sensor}: {split.words(flight.time_s)} (RMS, mG, upright samples).",
                              "", "| compass | calibration | rp in sample | \\|B\\| in sample | att held out | "
                              "rp held out | \\|B\\| held out | term and notes |",
                              "|---|---|---|---|---|---|---|---|"]  # fmt: skip
                    lines += holdout(path, flight, split, args.pymavlink_python, args.wmm_params, HELD_OUT_METHODS)
                    lines.append("")
    _write(args.out, lines)
    return 0


def _write(out: Path, lines: list[str]) -> None:
    """The tables between the results file's markers (the text around them, written by hand, is kept)."""
    begin, end = "<!-- tables: benchmarks/motor_real.py -->", "<!-- end of tables -->"
    text = out.read_text() if out.is_file() else f"{begin}\n{end}\n"
    head, _, rest = text.partition(begin)
    _, _, tail = rest.partition(end)
    out.write_text(f"{head}{begin}\n" + "\n".join(lines) + f"\n{end}{tail}")


if __name__ == "__main__":
    raise SystemExit(main())
