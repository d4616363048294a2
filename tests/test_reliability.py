"""Issue 11: bad input, faults and interruptions. One regression test per finding, named after it.

The invariants (docs/reliability.md): a MagfitError with a one-line message or a checked calibration;
exit status 0, 1 or 2, never 3; no traceback; no existing file changed by a failed run; no temporary
file left behind.
"""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

import magfit
from magfit.cli import cli


def _run(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(arg) for arg in args])


def _assert_error(result: Result, status: int, *fragments: str) -> str:
    """The run failed with ``status``; its last line, the only error, holds every fragment (after any warnings)."""
    assert result.exit_code == status, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), "a traceback escaped"
    lines = result.stderr.strip().splitlines()
    assert all(line.startswith(("magfit: error: ", "magfit: warning: ")) for line in lines), result.stderr
    assert lines[-1].startswith("magfit: error: ") and sum(line.startswith("magfit: error") for line in lines) == 1
    for fragment in fragments:
        assert fragment in lines[-1], lines[-1]
    return lines[-1]


def _samples(n: int = 500, seed: int = 1) -> np.ndarray:
    return magfit.scenario("mpu9250", "steel").simulate(n, seed=seed).samples


def _hard_iron_only(n: int = 2000, seed: int = 1) -> np.ndarray:
    """Samples the sphere fit is right for (no soft iron): magfit refuses it on the steel case."""
    return magfit.scenario("mpu9250", "none").simulate(n, seed=seed).samples


def _csv(path: Path, samples: np.ndarray) -> Path:
    np.savetxt(path, samples, fmt="%.10g", delimiter=",", header="mx,my,mz", comments="")
    return path


def _flat(path: Path) -> Path:
    """Level turns at zero inclination: samples in a plane, which no method can fit (exit status 1)."""
    flat = magfit.simulate(300, orientations="yaw", inclination_deg=0.0, field_strength=50.0, seed=2).samples
    return _csv(path, flat)


def _no_temporaries(folder: Path) -> None:
    assert not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")], "a temporary file was left behind"


# ---------------------------------------------------------------------- 1. apply on a float64 .npy


def test_1_apply_float64_npy_writes_the_calibrated_array(tmp_path: Path) -> None:
    samples = _samples()
    np.save(tmp_path / "s.npy", samples)  # float64, C order: np.load's memory map is read-only
    calibration = magfit.fit(samples, method="ellipsoid", diagnostics=False)
    (tmp_path / "cal.json").write_text(calibration.to_json())
    result = _run("apply", tmp_path / "cal.json", tmp_path / "s.npy", "-o", tmp_path / "out.npy")
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(np.load(tmp_path / "out.npy"), calibration.apply(samples), rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(np.load(tmp_path / "s.npy"), samples)  # the input is untouched


# ---------------------------------------------------------------------- 2. a failed run overwrites its output


def test_2_failed_run_keeps_the_existing_output(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    keep = tmp_path / "keep.json"
    keep.write_text("OLD\n")
    # The --plot folder is missing: refused before the fit, -o untouched.
    _assert_error(_run("calibrate", data, "-o", keep, "--plot", tmp_path / "nodir" / "p.png"), 2, "does not exist")
    assert keep.read_text() == "OLD\n"
    # The data cannot support the fit: exit 1, -o untouched.
    _assert_error(_run("calibrate", _flat(tmp_path / "flat.csv"), "-m", "ellipsoid", "-o", keep), 1, "plane")
    assert keep.read_text() == "OLD\n"
    _no_temporaries(tmp_path)


def test_2_same_path_for_two_outputs_is_a_usage_error(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    same = tmp_path / "same.png"
    _assert_error(_run("calibrate", data, "-o", same, "--plot", same), 2, "-o and --plot are the same file")
    assert not same.exists()
    same.write_bytes(b"OLD")  # through a link, too
    os.symlink(same, tmp_path / "link.png")
    _assert_error(_run("calibrate", data, "-o", tmp_path / "link.png", "--plot", same), 2, "same file")
    assert same.read_bytes() == b"OLD"


@pytest.mark.slow
def test_2_calibrate_writes_both_outputs_on_success(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    data = _csv(tmp_path / "s.csv", _samples())
    result = _run("calibrate", data, "-m", "ellipsoid", "-o", tmp_path / "cal.json", "--plot", tmp_path / "p.png")
    assert result.exit_code == 0, result.output
    saved = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    assert saved.method == "ellipsoid"
    assert (tmp_path / "p.png").read_bytes().startswith(b"\x89PNG")
    _no_temporaries(tmp_path)


def test_6_report_that_fails_keeps_the_existing_report(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    flat = _flat(tmp_path / "flat.csv")
    report = tmp_path / "report.html"
    report.write_text("OLD")
    result = _run("report", flat, "--methods", "ellipsoid", "-o", report)
    _assert_error(result, 1, "no method could fit", "--allow-unfitted")
    assert report.read_text() == "OLD"
    result = _run("report", flat, "--methods", "ellipsoid", "--allow-unfitted", "-o", report)
    assert result.exit_code == 0, result.output
    assert "No method could fit these samples" in report.read_text(encoding="utf-8")


# ---------------------------------------------------------------------- 3. FIFOs, devices, '-' as outputs


def test_3_dash_means_stdout(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    data = _csv(tmp_path / "s.csv", _samples())
    result = _run("calibrate", data, "-m", "ellipsoid", "-o", "-")
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(result.stdout)  # the JSON alone on stdout, the summary on stderr
    assert calibration.method == "ellipsoid"
    assert "offset" in result.stderr
    result = _run("apply", _saved(tmp_path, calibration), data, "-o", "-")
    assert result.exit_code == 0, result.output
    corrected = np.loadtxt(result.stdout.splitlines(), delimiter=",", skiprows=1)
    np.testing.assert_allclose(corrected, calibration.apply(np.loadtxt(data, delimiter=",", skiprows=1)), rtol=1e-8)
    assert not (tmp_path / "-").exists()


def _saved(folder: Path, calibration: magfit.Calibration) -> Path:
    path = folder / "cal.json"
    path.write_text(calibration.to_json())
    return path


@pytest.mark.skipif(not Path("/dev/null").exists(), reason="needs /dev/null")
def test_3_device_output_is_written_into_not_replaced(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    before = os.stat("/dev/null")
    result = _run("calibrate", data, "-m", "ellipsoid", "-o", "/dev/null")
    assert result.exit_code == 0, result.output
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_3_fifo_output_is_written_into(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    received: list[bytes] = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    result = _run("calibrate", data, "-m", "ellipsoid", "-o", fifo)
    reader.join(timeout=30)
    assert result.exit_code == 0, result.output
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert json.loads(received[0])["method"] == "ellipsoid"


def test_3_symbolic_links(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    os.symlink("real.json", tmp_path / "link.json")  # dangling: the file it names is created
    assert _run("calibrate", data, "-m", "ellipsoid", "-o", tmp_path / "link.json").exit_code == 0
    assert (tmp_path / "link.json").is_symlink()
    assert magfit.Calibration.from_json((tmp_path / "real.json").read_text()).method == "ellipsoid"
    os.symlink("loop2", tmp_path / "loop1")
    os.symlink("loop1", tmp_path / "loop2")
    _assert_error(_run("calibrate", data, "-o", tmp_path / "loop1"), 2, "symbolic link loop")
    _assert_error(_run("calibrate", data, "-o", tmp_path), 2)  # a directory


# ---------------------------------------------------------------------- 4. exit 3 on malformed input


def _broken_npy_files(folder: Path) -> dict[str, Path]:
    good = folder / "good.npy"
    np.save(good, _samples())
    files = {"truncated": folder / "truncated.npy", "object": folder / "object.npy", "0-d": folder / "zerod.npy"}
    files["truncated"].write_bytes(good.read_bytes()[:1000])
    np.save(files["object"], np.array([[1.0, "a", None]] * 5, dtype=object), allow_pickle=True)
    np.save(files["0-d"], np.array(3.0))
    return files


@pytest.mark.parametrize("command", [["calibrate", "-m", "sphere"], ["calibrate", "-m", "ml"], ["calibrate", "--even"]])
def test_4_malformed_npy_is_an_input_error(tmp_path: Path, command: list[str]) -> None:
    for kind, path in _broken_npy_files(tmp_path).items():
        message = _assert_error(_run(*command, path), 2, str(path))
        assert {"truncated": "is truncated", "object": "dtype object", "0-d": "shape ()"}[kind] in message


def test_4_malformed_npy_through_apply(tmp_path: Path) -> None:
    calibration = _saved(tmp_path, magfit.Calibration.identity(270.0))
    for path in _broken_npy_files(tmp_path).values():
        _assert_error(_run("apply", calibration, path, "-o", tmp_path / "out.npy"), 2, str(path))
    assert not (tmp_path / "out.npy").exists()


def _calibration_dict() -> dict[str, object]:
    return json.loads(magfit.fit(_samples(), method="ellipsoid").to_json())


def _mutated(**fields: object) -> str:
    return json.dumps({**_calibration_dict(), **fields})


#: Calibration files that are no usable calibration, and what the one-line refusal says.
BROKEN_CALIBRATIONS: dict[str, tuple[Callable[[], str | bytes], str]] = {
    "a number beyond float64": (
        lambda: _mutated(field_strength=1.0).replace('"field_strength": 1.0', '"field_strength": 1e400'),
        "'field_strength' is beyond the range of float64",
    ),
    "an integer beyond float64": (lambda: _mutated(offset=[10**400, 0, 0]), "'offset[0]' is beyond the range"),
    "a ragged matrix": (lambda: _mutated(matrix=[[1, 0, 0], [0, 1], [0, 0, 1]]), "'matrix[1]' must be a list of 3"),
    "strings for numbers": (lambda: _mutated(offset=["1", "2", "3"]), "'offset[0]' must be a number"),
    "details a list": (lambda: _mutated(details=[]), "'details' must be an object"),
    "diagnostics a list": (lambda: _mutated(details={"diagnostics": []}), "'details.diagnostics' must be an object"),
    "malformed diagnostics": (lambda: _mutated(details={"diagnostics": {"a": 1}}), "diagnostics"),
    "deep nesting": (lambda: _mutated(details={"x": 1}).replace('{"x": 1}', "[" * 100_000 + "]" * 100_000), "deeply"),
    "deep nesting in details": (lambda: _mutated(details={"x": 1}).replace("1}", "[" * 2000 + "]" * 2000 + "}"), ""),
    "a mirror matrix": (lambda: _mutated(matrix=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]), "mirror"),
    "a singular matrix": (lambda: _mutated(matrix=[[1, 0, 0], [0, 1, 0], [0, 0, 0]]), "singular"),
    "a denormal field strength": (lambda: _mutated(field_strength=1e-320), "field_strength must lie between"),
    "an absurd field strength": (lambda: _mutated(field_strength=1e308), "field_strength must lie between"),
    "a negative field strength": (lambda: _mutated(field_strength=-3.0), "positive"),
    "NaN": (lambda: _mutated(field_strength=1.0).replace('"field_strength": 1.0', '"field_strength": NaN'), "NaN"),
    "a boolean": (lambda: _mutated(field_strength=True), "must be a number"),
    "a count as a string": (lambda: _mutated(n_samples="5"), "'n_samples' must be a count"),
    "a number as unit": (lambda: _mutated(unit=5), "'unit' must be a string"),
    "no offset": (lambda: json.dumps({k: v for k, v in _calibration_dict().items() if k != "offset"}), "'offset'"),
    "an array": (lambda: "[1, 2]", "must be an object"),
    "not UTF-8 JSON": (lambda: b"\xff\xfe{", "not valid JSON"),
}


@pytest.mark.parametrize("case", BROKEN_CALIBRATIONS)
def test_4_from_json_refuses_what_is_no_calibration(case: str) -> None:
    make, fragment = BROKEN_CALIBRATIONS[case]
    with pytest.raises(magfit.MagfitError) as caught:
        magfit.Calibration.from_json(make())
    message = str(caught.value)
    assert "\n" not in message and fragment in message, message
    assert len(message) < 400


@pytest.mark.slow
def test_4_broken_calibration_file_through_apply(tmp_path: Path) -> None:
    data = _csv(tmp_path / "s.csv", _samples())
    for case, (make, _) in BROKEN_CALIBRATIONS.items():
        text = make()
        path = tmp_path / "cal.json"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        _assert_error(_run("apply", path, data, "--normalized", "-o", tmp_path / "out.csv"), 2, str(path))
        assert not (tmp_path / "out.csv").exists(), case


# ---------------------------------------------------------------------- 6. FIFOs and devices as input


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.slow
def test_6_a_silent_fifo_as_input_is_refused_after_a_short_wait(tmp_path: Path) -> None:
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    _assert_error(_run("calibrate", fifo), 2, "named pipe", "save the data to a file first")
    if Path("/dev/zero").exists():
        _assert_error(_run("calibrate", "/dev/zero"), 2, "a device")


# ---------------------------------------------------------------------- 5. overflow that depended on chunking


def test_5_a_value_whose_square_overflows_is_refused_whatever_the_chunking() -> None:
    samples = _samples(2000)
    statistics = magfit.Statistics().update(samples)
    with pytest.raises(magfit.SampleError, match=r"beyond ±1e\+150 in 1 row\(s\), the first is row 0 \(1e\+200\)"):
        statistics.update([[1e200, 0, 0]])
    # All or nothing: the statistics are those of the good samples, and they still fit.
    chunked = magfit.fit(statistics, method="ellipsoid", diagnostics=False)
    whole = magfit.fit(samples, method="ellipsoid", diagnostics=False)
    np.testing.assert_allclose(chunked.offset, whole.offset, rtol=1e-9)
    np.testing.assert_allclose(chunked.matrix, whole.matrix, rtol=1e-9)
    bad = np.vstack([samples, [[1e200, 0, 0]]])
    for chunk_size in (1, 7, 1000, 1 << 16):
        with pytest.raises(magfit.SampleError, match="the first is row 2000"):
            magfit.Statistics(chunk_size).update(bad)
    with pytest.raises(magfit.SampleError, match="beyond"):
        magfit.fit(_samples() * 1e181 + 1e198, method="sphere")


def test_5_csv_with_one_huge_row_after_a_full_chunk(tmp_path: Path) -> None:
    path = tmp_path / "big.csv"
    with path.open("w") as handle:
        handle.write("mx,my,mz\n")
        np.savetxt(handle, _samples(65_536), fmt="%.6f", delimiter=",")
        handle.write("1e200,0,0\n")
    # Skipped and counted as a NaN row is (a glitch no magnetometer reads); named with --nonfinite error.
    result = _run("calibrate", path, "-m", "ellipsoid")
    assert result.exit_code == 0, result.output
    assert "skipped 1 of 65537 rows" in result.stderr and "(lines 65538)" in result.stderr
    assert "Warning" not in result.stderr
    result = _run("calibrate", path, "-m", "ellipsoid", "--nonfinite", "error")
    _assert_error(result, 2, "line 65538, column 'mx'", "1e+200")


# ---------------------------------------------------------------------- 7. warnings and wrong reasons


def test_7_huge_values_are_refused_without_numpy_warnings() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would fail the test
        for samples in (_samples() * 1e303, np.full((50, 3), 1e305)):
            with pytest.raises(magfit.SampleError, match="beyond"):
                magfit.fit(samples, method="sphere")


def test_7_a_far_offset_is_not_identical_samples() -> None:
    rng = np.random.default_rng(0)
    flat = np.column_stack([np.full(500, 1e15), rng.uniform(-200, 200, (500, 2))])
    with pytest.raises(magfit.CalibrationError, match="lie in a plane: nothing varies along the sensor x axis"):
        magfit.fit(flat)
    # A full sphere of radius 270 at x = 1e15 (float64 resolves 0.125 there): it fits, at the right place.
    simulation = magfit.scenario("mpu9250", "none").simulate(2000, seed=3)
    shifted = simulation.samples + np.array([1e15, 0, 0])
    calibration = magfit.fit(shifted, method="sphere", diagnostics=False)
    np.testing.assert_allclose(calibration.offset - [1e15, 0, 0], simulation.truth.offset, atol=3.0)
    assert calibration.field_strength == pytest.approx(simulation.truth.field_strength, rel=0.02)


def _recording_for(method: str) -> np.ndarray:
    """Samples the method is right for: magfit refuses the hard-iron-only models on the steel case."""
    return _hard_iron_only() if method in ("sphere", "diag", "minmax") else _samples(2000)


@pytest.mark.parametrize("scale", [1e-35, 1e35])
@pytest.mark.parametrize("method", sorted(name for name, spec in magfit.METHODS.items() if not spec.needs))
@pytest.mark.slow
def test_7_data_far_from_unit_scale_fit_without_warnings(method: str, scale: float) -> None:
    samples = _recording_for(method)
    reference = magfit.fit(samples, method=method, diagnostics=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would fail the test
        scaled = magfit.fit(samples * scale, method=method)
    assert scaled.field_strength / scale == pytest.approx(reference.field_strength, rel=1e-6)
    np.testing.assert_allclose(scaled.offset / scale, reference.offset, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("scale", [1e-60, 1e55, 1e100, 1e146])
@pytest.mark.parametrize("method", sorted(magfit.METHODS))
def test_7_data_beyond_the_fitted_range_are_refused_for_that_reason(method: str, scale: float) -> None:
    # Before: "Calibration.matrix contains NaN or inf", "hyperboloid", a sphere chosen by auto, numpy warnings.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(magfit.SampleError, match=r"the samples spread .* outside the 1e-40 to 1e\+40 .* rescale"):
            magfit.fit(_recording_for(method) * scale, method=method)


def test_7_carriage_return_line_ends(tmp_path: Path) -> None:
    rows = "\r".join(",".join(f"{v:.6f}" for v in row) for row in _samples())
    path = tmp_path / "mac.csv"
    path.write_bytes(("mx,my,mz\r" + rows + "\r").encode())
    _assert_error(_run("calibrate", path), 2, "carriage return only", "tr ")


def test_7_a_very_long_line_before_the_data(tmp_path: Path) -> None:
    rows = "\n".join(",".join(f"{v:.6f}" for v in row) for row in _samples())
    path = tmp_path / "long.csv"
    path.write_text("# " + "x" * 300_000 + "\nmx,my,mz\n" + rows + "\n")
    result = _run("calibrate", path, "-m", "ellipsoid")
    assert result.exit_code == 0, result.output
    assert "500 read" in result.stdout
    header_only = tmp_path / "header_only.csv"
    header_only.write_text("mx,my," + "z" * 300_000 + "\n")
    message = _assert_error(_run("calibrate", header_only), 2, "no data rows")
    assert len(message) < 300


# ---------------------------------------------------------------------- 6. interruptions


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """300 000 rows (about a second of 'magfit apply') and a calibration for them."""
    folder = tmp_path_factory.mktemp("long")
    samples = _samples(1000)
    block = "".join(f"{x:.4f},{y:.4f},{z:.4f}\n" for x, y, z in samples)
    (folder / "long.csv").write_text("mx,my,mz\n" + block * 300)
    return folder / "long.csv", _saved(folder, magfit.fit(samples, method="ellipsoid", diagnostics=False))


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize(("signum", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
@pytest.mark.external
@pytest.mark.slow
def test_6_a_signal_while_writing_leaves_no_temporary_file(
    long_recording: tuple[Path, Path], tmp_path: Path, signum: int, status: int
) -> None:
    data, calibration = long_recording
    output = tmp_path / "out.csv"
    output.write_text("OLD\n")
    command = [sys.executable, "-c", "import sys; from magfit.cli import main; sys.exit(main())"]
    process = subprocess.Popen(
        [*command, "apply", str(calibration), str(data), "-o", str(output)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".out.csv.*.tmp")):  # the temporary output exists: the writing has begun
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == status, stderr
    assert stderr.strip().splitlines() == [
        f"magfit: interrupted ({signal.Signals(signum).name}); existing files are left as they were"
    ]
    assert output.read_text() == "OLD\n"
    _no_temporaries(tmp_path)


def test_running_out_of_memory_is_no_bug() -> None:
    from magfit.cli._common import EXIT_USAGE, as_command_error

    error = as_command_error(MemoryError())
    assert error.exit_code == EXIT_USAGE and "not enough memory" in error.format_message()


# ---------------------------------------------------------------------- found by tests/test_fuzz.py


def _rows(n: int = 60) -> list[str]:
    return [f"{t},{x:.4f},{y:.4f},{z:.4f}" for t, (x, y, z) in enumerate(_samples(n))]


def test_fuzz_a_carriage_return_inside_a_line(tmp_path: Path) -> None:
    rows = _rows()
    rows[0] = rows[0].replace(",", "\r,", 1)  # pandas ends a line there, magfit's line count does not
    path = tmp_path / "cr_inside.csv"
    path.write_bytes(("time,mx,my,mz\n" + "\n".join(rows) + "\n").encode())
    _assert_error(_run("calibrate", path), 2, "line 2 holds a carriage return")


def test_fuzz_apply_on_rows_whose_field_counts_compensate(tmp_path: Path) -> None:
    rows = _rows()
    rows[10] = rows[10].replace(",", "", 1)  # one field short ...
    rows[20] = rows[20] + ",1,2"  # ... and two too many: the file's delimiter count is still right, off by one
    rows[30] = rows[30].replace(",", "", 1)
    path = tmp_path / "ragged.csv"
    path.write_text("time,mx,my,mz\n" + "\n".join(rows) + "\n")
    calibration = _saved(tmp_path, magfit.Calibration.identity(270.0))
    _assert_error(_run("apply", calibration, path, "-o", tmp_path / "out.csv"), 2, "line 12 has 3 fields")
    assert not (tmp_path / "out.csv").exists()


def test_fuzz_a_damaged_npy_header(tmp_path: Path) -> None:
    path = tmp_path / "damaged.npy"
    np.save(path, _samples(20))
    data = bytearray(path.read_bytes())
    data[60:70] = b"\x00" * 10  # inside the header's Python literal: numpy raises a TokenError
    path.write_bytes(bytes(data))
    _assert_error(_run("calibrate", path), 2, "is not a readable .npy file")


def test_2_simulate_checks_both_outputs_before_writing(tmp_path: Path) -> None:
    keep = tmp_path / "keep.csv"
    keep.write_text("OLD\n")
    result = _run("simulate", "-n", "50", "-o", keep, "--truth", tmp_path / "nodir" / "t.json", "--force")
    _assert_error(result, 2, "does not exist")
    assert keep.read_text() == "OLD\n"


@pytest.mark.slow
def test_2_plot_checks_its_output_first_and_writes_it_atomically(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    data = _csv(tmp_path / "s.csv", _samples())
    _assert_error(_run("plot", data, "-o", tmp_path / "nodir" / "p.png"), 2, "does not exist")
    result = _run("plot", data, "-m", "ellipsoid", "--methods", "ellipsoid", "-o", tmp_path / "p.png")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p.png").read_bytes().startswith(b"\x89PNG")
    _no_temporaries(tmp_path)


def test_fuzz_denormal_and_tiny_samples_are_refused_for_their_spread() -> None:
    # Denormal values (a damaged .npy): the frame's unit was denormal, 1 / unit inf, the scatter NaN with a
    # numpy warning; 1e-200 samples were "all identical" (their covariance underflowed in input units).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for samples in (_hard_iron_only(100) * 1e-319, _hard_iron_only(500) * 1e-200):
            statistics = magfit.Statistics().update(samples)
            assert statistics.n == len(samples)
            with pytest.raises(magfit.SampleError, match=r"the samples spread .* outside the 1e-40 to 1e\+40"):
                magfit.fit(samples, method="sphere")


def test_fuzz_identical_samples_in_single_rows_keep_finite_statistics() -> None:
    # Halving a denormal rounded the running mean, the round-off became a "spread", the frame shrank to it
    # and the scatter overflowed to NaN: merged statistics had a NaN mean.
    samples = np.array([[20, 338, -370]] * 3 + [[8, 291, -451]] * 3 + [[4.94e-324, 100, -512]] * 3, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        merged = magfit.Statistics(1).update(samples[:6]).merge(magfit.Statistics(1).update(samples[6:]))
        np.testing.assert_allclose(merged.mean, samples.mean(axis=0), rtol=1e-12)
        identical = magfit.Statistics(1).update(np.array([[1e-300, 100, -512]] * 20))
        with pytest.raises(magfit.CalibrationError, match="identical"):
            magfit.fit(identical, method="ellipsoid")


def test_fuzz_a_quote_before_a_lone_carriage_return(tmp_path: Path) -> None:
    path = tmp_path / "quote.txt"
    path.write_bytes(b'\n\r"')  # Python's csv module raised csv.Error: exit 3
    _assert_error(_run("calibrate", path), 2, str(path))
