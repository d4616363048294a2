"""The fuzz campaign of issue 11, kept: hypothesis properties over every entry point that takes outside input.

The invariants (docs/reliability.md):

- the library returns a checked result (finite offset and matrix, a positive determinant, a field strength in
  range) or raises a :class:`magfit.MagfitError` whose message is one line; never another exception;
- the command line exits 0, 1 or 2 (never 3: a bug), prints no traceback, changes no existing file when it
  fails and leaves no temporary file.

Bounded for CI: about 430 examples in all, 15-30 seconds. ``MAGFIT_FUZZ_EXAMPLES=N`` multiplies the
budget of every test by N / 100 for a long run (e.g. ``MAGFIT_FUZZ_EXAMPLES=5000`` for an overnight one).
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import sys
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import magfit
from magfit.calibration import FIELD_STRENGTH_RANGE

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # accuracy's truth metric

#: Examples per test are scaled by this / 100 (the default budget: the numbers written in each test).
SCALE = int(os.environ.get("MAGFIT_FUZZ_EXAMPLES", "100")) / 100


def budget(examples: int) -> Any:
    """Hypothesis settings for a test of ``examples`` examples at the default scale (no deadline: fits vary)."""
    return settings(
        max_examples=max(1, int(examples * SCALE)),
        deadline=None,
        print_blob=True,  # a failure prints @reproduce_failure(...): the example's seed, to rerun it alone
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )


BASE_SIMULATION = magfit.scenario("mpu9250", "steel").simulate(400, seed=11)
SPHERE_SIMULATION = magfit.scenario("mpu9250", "none").simulate(400, seed=12)
BASE = BASE_SIMULATION.samples
SPHERE = SPHERE_SIMULATION.samples
#: A returned calibration's level heading is within this many stated one-sigmas of the truth (or within FLOOR_DEG).
COVER = 3.0
FLOOR_DEG = 0.1


def check_calibration(calibration: magfit.Calibration) -> None:
    """A calibration magfit may hand out: finite, invertible and right-handed, in range, serialisable."""
    assert np.isfinite(calibration.offset).all() and np.isfinite(calibration.matrix).all()
    assert np.linalg.det(calibration.matrix) > 0
    low, high = FIELD_STRENGTH_RANGE
    assert low <= calibration.field_strength <= high
    assert magfit.Calibration.from_json(calibration.to_json()) == calibration


def check_error(error: BaseException) -> None:
    """Only magfit's own errors, with a one-line message that says something."""
    assert isinstance(error, magfit.MagfitError), f"{type(error).__name__}: {error}"
    message = str(error)
    assert message and "\n" not in message, message


def outcome(call: Callable[[], Any]) -> Any:
    """The result of ``call``, or None after checking that it raised a proper MagfitError."""
    try:
        return call()
    except Exception as error:  # the property: nothing but a MagfitError
        check_error(error)
        return None


# ---------------------------------------------------------------------- samples


class Bent(np.ndarray):
    """A recording bent out of shape, with the truth it still has: ``truth`` is None once it has none."""

    truth: tuple[magfit.Simulation, float, float] | None  # (simulation, scale, shift): samples = scale x + shift


def _recordings() -> st.SearchStrategy[np.ndarray]:
    """Good recordings bent out of shape: scaled, shifted, flattened, cut short, spiked, duplicated.

    Scaling and shifting keep a truth (the simulation's, scaled and shifted the same way); flattening an
    axis, spiking rows or keeping a few distinct samples do not.
    """

    @st.composite
    def build(draw: st.DrawFn) -> np.ndarray:
        simulation = BASE_SIMULATION if draw(st.booleans()) else SPHERE_SIMULATION
        samples = simulation.samples.copy()
        samples = samples[: draw(st.integers(0, len(samples)))]
        scale = 10.0 ** draw(st.integers(-40, 40))
        shift = 10.0 ** draw(st.integers(-5, 60)) * draw(st.sampled_from([0.0, 1.0, -1.0]))
        samples = samples * scale + shift
        kept = True
        if len(samples) and draw(st.booleans()):
            samples[:, draw(st.integers(0, 2))] = draw(st.sampled_from([0.0, 1e15, -3.5]))  # a flat axis
            kept = False
        if len(samples) and draw(st.booleans()):
            rows = draw(st.lists(st.integers(0, len(samples) - 1), max_size=5))
            value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e200, -1e300, 1e151, 0.0, 5e-324]))
            samples[rows, draw(st.integers(0, 2))] = value
            kept = kept and not rows
        if draw(st.booleans()):
            samples = np.repeat(samples[:3], draw(st.integers(1, 50)), axis=0)  # few distinct samples
            kept = False
        bent = samples.view(Bent)
        # The truth survives where the shift does not swallow the field (float64 keeps 15 digits of it).
        bent.truth = (simulation, scale, shift) if kept and abs(shift) <= 1e6 * scale else None
        return bent

    return build()


def check_against_truth(calibration: magfit.Calibration, truth: tuple[magfit.Simulation, float, float]) -> None:
    """The calibration's level heading is within its stated uncertainty of the truth (accuracy benchmark metric)."""
    from _common import heading_error_deg

    simulation, scale, shift = truth
    unbent = magfit.Calibration(
        calibration.method,
        (np.asarray(calibration.offset) - shift) / scale,
        calibration.matrix,
        calibration.field_strength / scale,
    )
    error = heading_error_deg(unbent, simulation)
    report = calibration.diagnostics
    stated = report.uncertainty.heading_sigma_deg if report is not None and report.uncertainty is not None else None
    assert stated is not None, "a returned calibration states its heading uncertainty"
    assert error <= max(COVER * stated, FLOOR_DEG), (calibration.method, error, stated)


def _arbitrary_arrays() -> st.SearchStrategy[Any]:
    """Whatever a caller might pass: odd shapes, dtypes, lists, scalars, strings."""
    floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
    return st.one_of(
        st.lists(st.lists(floats, min_size=3, max_size=3), max_size=30).map(np.array),
        st.lists(st.lists(floats, max_size=4), max_size=5),
        st.integers(0, 12).flatmap(lambda n: st.just(np.zeros((3, n)))),
        st.sampled_from([None, "samples", 3.0, np.zeros(3), np.zeros((0, 3)), np.zeros((5, 3), dtype=complex)]),
        st.integers(1, 40).map(lambda n: np.arange(3 * n, dtype=np.int16).reshape(n, 3)),
        st.integers(1, 40).map(lambda n: BASE[:n].astype(np.float32)),
    )


MAGNITUDE_METHODS = sorted(name for name, spec in magfit.METHODS.items() if not spec.needs)


@pytest.mark.parametrize("method", MAGNITUDE_METHODS)
@budget(12)
@given(samples=st.one_of(_recordings(), _arbitrary_arrays()))
def test_fit_gives_a_checked_calibration_or_a_magfit_error(method: str, samples: Any) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # an overflow must be avoided or handled, not warned
        calibration = outcome(lambda: magfit.fit(samples, method=method))
    if calibration is not None:
        check_calibration(calibration)
        outcome(lambda: calibration.diagnostics)
        truth = getattr(samples, "truth", None)
        if truth is not None:
            check_against_truth(calibration, truth)


@pytest.mark.parametrize("method", MAGNITUDE_METHODS)
@budget(6)
@given(
    steel=st.booleans(),
    cut=st.integers(8, 400),
    scale_exponent=st.integers(-40, 40),
    shift=st.floats(-1e5, 1e5),
)
@pytest.mark.slow
def test_a_fit_of_a_scaled_recording_is_within_its_stated_uncertainty_or_refused(
    method: str, steel: bool, cut: int, scale_exponent: int, shift: float
) -> None:
    # The truth survives scaling and shifting (the simulation's, scaled and shifted alike): a returned
    # calibration's level heading must lie within COVER of its stated one-sigmas of it.
    simulation = BASE_SIMULATION if steel else SPHERE_SIMULATION
    scale = 10.0**scale_exponent
    samples = simulation.samples[:cut] * scale + shift * scale
    calibration = outcome(lambda: magfit.fit(samples, method=method))
    if calibration is not None:
        check_calibration(calibration)
        check_against_truth(calibration, (simulation, scale, shift * scale))


def _vehicle_recording() -> Any:
    from magfit.vehicle import simulate_vehicle

    # A tumble both methods accept whole ("supported"): the fuzz then bends it.
    return simulate_vehicle(
        600, "tumble", rate_hz=10.0, hard_iron=[0.3, -0.2, 0.1], noise=0.005, attitude_noise_deg=0.3,
        gyro_noise=0.002, seed=5,
    )  # fmt: skip


VEHICLE = _vehicle_recording()


@pytest.mark.parametrize("method", sorted(name for name, spec in magfit.METHODS.items() if spec.needs))
@budget(4)
@given(
    cut=st.one_of(st.just(600), st.integers(0, 600)),
    scale=st.sampled_from([1e-6, 1.0, 1e6]),
    spikes=st.lists(st.integers(0, 599), max_size=4),
    value=st.sampled_from([np.nan, np.inf, 1e200, 0.0]),
)
def test_fit_with_a_reference_or_gyro_gives_a_checked_calibration_or_a_magfit_error(
    method: str, cut: int, scale: float, spikes: list[int], value: float
) -> None:
    # vector and gyro run on what they need beside the samples (a reference field, body rates): without it
    # they would stop at the OptionError before the method. Their accuracy against the truth is
    # tests/test_vehicle.py's and tests/test_vector.py's.
    samples = VEHICLE.samples[:cut] * scale
    samples[[i for i in spikes if i < cut], 0] = value
    streams: dict[str, Any] = {"time_s": VEHICLE.time_s[:cut]}
    if method in ("vector", "tilt"):
        streams["reference"] = VEHICLE.reference[:cut] * scale
    else:
        streams["gyro"] = VEHICLE.gyro[:cut]
    if method == "tilt":  # the logged attitude's vertical in the vehicle frame (attitude: vehicle -> north-east-down)
        streams = {"reference": streams["reference"], "down": VEHICLE.attitude_measured[:cut, 2, :]}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        calibration = outcome(lambda: magfit.fit(samples, method=method, **streams))
    if cut == 600 and not spikes and scale == 1.0:
        assert calibration is not None, "the whole tumble is accepted: the method itself ran"
    if calibration is not None:
        check_calibration(calibration)
        assert calibration.frame == "vehicle"


# ---------------------------------------------------------------------- Statistics


@budget(40)
@given(samples=_recordings(), cuts=st.lists(st.integers(0, 400), max_size=6), chunk_size=st.integers(1, 500))
def test_statistics_update_and_merge(samples: np.ndarray, cuts: list[int], chunk_size: int) -> None:
    whole = outcome(lambda: magfit.Statistics(chunk_size).update(samples))
    pieces = np.split(samples, sorted(min(cut, len(samples)) for cut in cuts))
    parts = []
    for piece in pieces:
        part = magfit.Statistics(chunk_size)
        if outcome(lambda piece=piece, part=part: part.update(piece)) is None:
            assert part.n == 0  # all or nothing
        parts.append(part)
    # Whether the samples are refused does not depend on how they are split.
    refused = any(p.n != len(piece) for p, piece in zip(parts, pieces, strict=True))
    assert refused == (whole is None)
    if whole is None or whole.n == 0:
        return
    merged = sum(parts[1:], parts[0])
    assert merged.n == whole.n
    scale = max(whole.scale, float(np.max(np.abs(whole.mean))) * 1e-15, np.finfo(float).tiny)
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-9, atol=1e-9 * scale)
    # The scatter the linear fits solve from, not only the mean: normalised, it is O(1) per entry.
    big = float(np.max(np.abs(whole.scatter)))
    np.testing.assert_allclose(merged.scatter, whole.scatter, rtol=1e-7, atol=1e-9 * big)


# ---------------------------------------------------------------------- Calibration.from_json

_GOOD_TEXT = magfit.fit(BASE, method="ellipsoid").to_json()
_GOOD = json.loads(_GOOD_TEXT)
_JSON_VALUES = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(10**400), 10**400),
        st.floats(allow_nan=False, allow_infinity=False),
        st.text(max_size=10),
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12,
)


def _paths(value: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every place in a JSON document (dict keys and list indices)."""
    places = [prefix]
    if isinstance(value, dict):
        for key, item in value.items():
            places += _paths(item, (*prefix, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            places += _paths(item, (*prefix, index))
    return places


_PLACES = [place for place in _paths(_GOOD) if place]


def _replaced(document: Any, place: tuple[Any, ...], value: Any) -> Any:
    if not place:
        return value
    copy = dict(document) if isinstance(document, dict) else list(document)
    copy[place[0]] = _replaced(document[place[0]], place[1:], value)
    return copy


@budget(60)
@given(place=st.sampled_from(_PLACES), value=_JSON_VALUES, drop=st.booleans())
def test_from_json_on_mutated_calibrations(place: tuple[Any, ...], value: Any, drop: bool) -> None:
    document = _replaced(_GOOD, place, value)
    if drop and len(place) == 1:
        document = {key: item for key, item in document.items() if key != place[0]}
    calibration = outcome(lambda: magfit.Calibration.from_json(json.dumps(document)))
    if calibration is not None:
        check_calibration(calibration)
        assert np.isfinite(calibration.apply(BASE[:5], normalized=True)).all()
        calibration.diagnostics  # noqa: B018 - a file that was accepted has a readable report


@budget(30)
@given(
    text=st.one_of(
        st.text(max_size=200),
        st.binary(max_size=200),
        st.builds(lambda cut: _GOOD_TEXT[:cut], st.integers(0, len(_GOOD_TEXT))),
        st.just(_GOOD_TEXT),
        st.integers(1, 3000).map(lambda depth: '{"details": ' + "[" * depth + "]" * depth + "}"),
    )
)
def test_from_json_on_arbitrary_text(text: str | bytes) -> None:
    calibration = outcome(lambda: magfit.Calibration.from_json(text))
    if calibration is not None:
        check_calibration(calibration)
    if text == _GOOD_TEXT:  # the whole document is read back as it was written
        assert calibration is not None and calibration.to_json() == magfit.Calibration.from_json(_GOOD_TEXT).to_json()


# ---------------------------------------------------------------------- export


@st.composite
def _calibrations(draw: st.DrawFn) -> magfit.Calibration:
    # Up to the ends of the field-strength range and offsets near float64's limit: a unit conversion (x 1e9 from
    # tesla to nT, x 1e5 from gauss) or a product in a firmware's arithmetic can overflow to inf, which the
    # export must refuse rather than write.
    exponent = draw(st.one_of(st.integers(-6, 7), st.integers(-149, 149)))
    strength = 10.0**exponent * draw(st.floats(0.5, 2.0))
    offset = np.array(draw(st.lists(st.floats(-50, 50), min_size=3, max_size=3))) * 10.0 ** draw(
        st.one_of(st.integers(-6, 9), st.integers(-300, 306))
    )
    skew = np.array(draw(st.lists(st.floats(-0.4, 0.4), min_size=9, max_size=9))).reshape(3, 3)
    matrix = np.eye(3) + skew
    determinant = np.linalg.det(matrix)
    if determinant <= 1e-3:
        matrix = np.eye(3)
        determinant = 1.0
    matrix = matrix / np.cbrt(determinant)
    unit = draw(st.sampled_from([None, "uT", "nT", "mT", "mG", "gauss", "G", "T", "counts", "furlongs"]))
    return magfit.Calibration(draw(st.sampled_from(["ellipsoid", "sphere"])), offset, matrix, strength, unit=unit)


def _export_formats() -> list[str]:
    from magfit.export import FORMATS

    return sorted(FORMATS)


@pytest.mark.parametrize("format", _export_formats())
@budget(6)
@given(calibration=_calibrations(), unit=st.sampled_from([None, "uT", "mG", "counts", "parsecs"]))
def test_export_writes_text_or_refuses(format: str, calibration: magfit.Calibration, unit: str | None) -> None:
    from magfit.export import export

    text = outcome(lambda: export(calibration, format, unit=unit))
    if text is not None:
        assert isinstance(text, str) and text
        assert not re.search(r"\b(nan|inf)\b", text, re.IGNORECASE), text


# ---------------------------------------------------------------------- readers


def _good_csv() -> bytes:
    rows = "".join(f"{t},{x:.4f},{y:.4f},{z:.4f}\n" for t, (x, y, z) in enumerate(BASE[:120]))
    return ("time,mx,my,mz\n" + rows).encode()


@st.composite
def _mutated_bytes(draw: st.DrawFn, original: bytes) -> bytes:
    data = bytearray(original)
    for _ in range(draw(st.integers(1, 6))):
        if not data:
            break
        position = draw(st.integers(0, len(data) - 1))
        action = draw(st.sampled_from(["delete", "insert", "replace", "truncate", "duplicate"]))
        chunk = draw(
            st.sampled_from(
                [b"\r", b"\n", b",", b";", b"\t", b" ", b'"', b"\x00", b"\xff", b"nan", b"inf", b"1e999", b"-",
                 b"\xef\xbb\xbf", b"x" * 5000, b"1e200", b"mx"]
            )
        )  # fmt: skip
        if action == "delete":
            del data[position : position + draw(st.integers(1, 50))]
        elif action == "insert":
            data[position:position] = chunk
        elif action == "replace":
            data[position : position + len(chunk)] = chunk
        elif action == "truncate":
            del data[position:]
        else:
            data[position:position] = data[position : position + draw(st.integers(1, 200))]
    return bytes(data)


def _npy_bytes(array: np.ndarray) -> bytes:
    import io

    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


_GOOD_NPY = _npy_bytes(BASE[:100])


def _npz_bytes(compressed: bool) -> bytes:
    import io

    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, t=np.arange(100.0), mag=BASE[:100])
    return buffer.getvalue()


_ODD_NPY = [
    _npy_bytes(np.zeros((4, 3), dtype=np.complex128)),
    _npy_bytes(np.array(2.0)),
    _npy_bytes(BASE[:9].T),
    _npy_bytes(np.zeros((0, 3))),
    _GOOD_NPY[:200],
    _GOOD_NPY[:60] + struct.pack("<d", math.nan) * 40,
]
_FILES = st.one_of(
    st.tuples(st.just(".csv"), _mutated_bytes(_good_csv())),
    st.tuples(st.just(".npy"), _mutated_bytes(_GOOD_NPY)),
    st.tuples(st.just(".txt"), st.binary(max_size=300)),
    st.tuples(st.just(".npy"), st.sampled_from(_ODD_NPY)),
    st.tuples(st.just(".npz"), st.booleans().flatmap(lambda packed: _mutated_bytes(_npz_bytes(packed)))),
)


@budget(60)
@given(file=_FILES)
def test_readers_give_finite_samples_or_a_magfit_error(file: tuple[str, bytes]) -> None:
    from magfit.io import read_samples

    suffix, data = file
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"samples{suffix}"
        path.write_bytes(data)
        table = outcome(lambda: read_samples(path))
        if table is not None:
            assert table.samples.ndim == 2 and table.samples.shape[1] == 3
            assert np.isfinite(table.samples).all()


# ---------------------------------------------------------------------- the command line


_COMMANDS = [
    ["calibrate", "{file}", "-o", "{out}.json"],
    ["calibrate", "{file}", "-m", "sphere", "--export", "px4", "-o", "{out}.params", "--plot", "{out}.png"],
    ["compare", "{file}", "--format", "json"],
    ["apply", "{cal}", "{file}", "-o", "{out}{suffix}"],
]


@budget(40)
@given(file=_FILES, command=st.sampled_from(_COMMANDS), broken_calibration=st.booleans())
def test_cli_on_malformed_files(file: tuple[str, bytes], command: list[str], broken_calibration: bool) -> None:
    from magfit.cli import cli

    suffix, data = file
    with tempfile.TemporaryDirectory() as folder_name:
        folder = Path(folder_name)
        path = folder / f"samples{suffix}"
        path.write_bytes(data)
        calibration = folder / "cal.json"
        text = magfit.Calibration.identity(270.0).to_json()
        calibration.write_text(text[: len(text) // 2] if broken_calibration else text)
        out = folder / "out"
        existing = {p: b"OLD" for p in (folder / "out.json", folder / "out.params", folder / f"out{suffix}")}
        for p, content in existing.items():
            p.write_bytes(content)
        before = {p.name: p.read_bytes() for p in folder.iterdir()}
        args = [a.format(file=path, out=out, cal=calibration, suffix=suffix) for a in command]
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # numpy's warnings before an error: a cause not handled
            result = CliRunner().invoke(cli, args)
        assert result.exit_code in (0, 1, 2), (result.exit_code, result.output)
        assert result.exception is None or isinstance(result.exception, SystemExit), "a traceback escaped"
        assert "Traceback" not in result.output
        errors = [line for line in result.stderr.splitlines() if line.startswith("magfit: error:")]
        # One error line for a usage or input error; status 1 may also be compare's "no method fits a file".
        assert len(errors) == (result.exit_code == 2) or (result.exit_code == 1 and len(errors) <= 1), result.stderr
        assert not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]
        if result.exit_code != 0:
            assert {p.name: p.read_bytes() for p in folder.iterdir()} == before, "a failed run changed a file"


#: Real recordings of three layouts: tab-separated without a header, a header with many columns, a log
#: with a preamble (../shared/data/real; the test is skipped without them, a failure under CI).
REAL_FILES = (
    "fxos8700_magneto/mag-readings.txt",
    "hamagure_gauss/data-set_1.csv",
    "betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt",
)


@pytest.mark.parametrize("name", REAL_FILES)
@budget(10)
@given(data=st.data())
@pytest.mark.slow
def test_cli_on_damaged_real_recordings(real_data_dir: Path, name: str, data: st.DataObject) -> None:
    from magfit.cli import cli

    original = (real_data_dir / name).read_bytes()[:60_000]  # the head: the damage lands where it is read
    damaged = data.draw(_mutated_bytes(original))
    with tempfile.TemporaryDirectory() as folder_name:
        folder = Path(folder_name)
        path = folder / Path(name).name
        path.write_bytes(damaged)
        (folder / "cal.json").write_text("OLD")
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            result = CliRunner().invoke(cli, ["calibrate", str(path), "-o", str(folder / "cal.json")])
        assert result.exit_code in (0, 1, 2), (result.exit_code, result.output)
        assert result.exception is None or isinstance(result.exception, SystemExit), "a traceback escaped"
        if result.exit_code == 0:
            check_calibration(magfit.Calibration.from_json((folder / "cal.json").read_text()))
        else:
            assert (folder / "cal.json").read_text() == "OLD"
        assert not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]
