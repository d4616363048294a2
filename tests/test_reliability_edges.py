"""The second fuzz and security campaign's edges: hangs, damaged compressed files, damaged bags, decompression
bombs, unusable calibrations, the live session's bad lines and cut rows, the web view, an ambiguous .npz and
a closed pipe. One regression test per finding, rebuilding its reproducer (docs/reliability.md).

Every test that could hang runs its command on a thread joined with a timeout, with the pipe wait lowered.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner, Result

import magfit
import magfit.io.sources as sources
from magfit.cli import cli

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")


def _run(*args: object, input: bytes | None = None) -> Result:
    return CliRunner().invoke(cli, [str(arg) for arg in args], input=input)


def _within(seconds: float, call: Callable[[], Any]) -> Any:
    """``call()``'s result, failing the test (not hanging it) when it takes longer than ``seconds``."""
    box: list[Any] = []
    worker = threading.Thread(target=lambda: box.append(call()), daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), f"still running after {seconds} s: a hang"
    return box[0]


def _error(result: Result, status: int, *fragments: str) -> str:
    """The run failed with ``status`` and one line ``magfit: error: ...`` holding every fragment, no traceback."""
    assert result.exit_code == status, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), "a traceback escaped"
    lines = result.stderr.strip().splitlines()
    assert lines and lines[-1].startswith("magfit: error: "), result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[-1], lines[-1]
    return lines[-1]


def _samples(n: int = 500, seed: int = 1) -> np.ndarray:
    return magfit.scenario("mpu9250", "steel").simulate(n, seed=seed).samples


def _csv(path: Path, samples: np.ndarray) -> Path:
    np.savetxt(path, samples, fmt="%.10g", delimiter=",", header="mx,my,mz", comments="")
    return path


@pytest.fixture
def short_pipe_wait(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sources, "PIPE_WAIT_SECONDS", 0.3)


@pytest.fixture
def calibrated(tmp_path: Path) -> tuple[Path, Path, magfit.Calibration]:
    """A samples file, its saved ellipsoid calibration and the calibration."""
    samples = _samples()
    data = _csv(tmp_path / "s.csv", samples)
    calibration = magfit.fit(samples, method="ellipsoid", diagnostics=False)
    saved = tmp_path / "cal.json"
    saved.write_text(calibration.to_json())
    return data, saved, calibration


# ---------------------------------------------------------------------- named pipes: read once, never wait for ever

SIX_COMMANDS = {
    "calibrate": ["calibrate", "{fifo}", "-m", "ellipsoid"],
    "compare": ["compare", "{fifo}"],
    "inspect": ["inspect", "{fifo}"],
    "apply": ["apply", "{cal}", "{fifo}", "-o", "{out}/applied.csv"],
    "plot": ["plot", "{fifo}", "-o", "{out}/p.png"],
    "report": ["report", "{fifo}", "-o", "{out}/r.html"],
}


@needs_fifo
@pytest.mark.parametrize("command", list(SIX_COMMANDS))
@pytest.mark.slow
def test_a_fifo_with_a_writer_is_read_once_by_every_command(
    command: str, tmp_path: Path, calibrated: tuple[Path, Path, magfit.Calibration]
) -> None:
    if command in ("plot", "report"):
        pytest.importorskip("matplotlib")
    data, saved, _ = calibrated
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_bytes(data.read_bytes()), daemon=True)
    writer.start()
    args = [part.format(fifo=fifo, cal=saved, out=tmp_path) for part in SIX_COMMANDS[command]]
    result = _within(60, lambda: _run(*args))
    writer.join(5)
    assert result.exit_code == 0, result.output
    if command == "apply":  # the rows that went through the pipe, corrected
        _, _, calibration = calibrated
        written = np.loadtxt(tmp_path / "applied.csv", delimiter=",", skiprows=1)
        np.testing.assert_allclose(written, calibration.apply(np.loadtxt(data, delimiter=",", skiprows=1)), rtol=1e-8)


@needs_fifo
def test_a_fifo_output_without_a_reader_is_refused_in_time(
    tmp_path: Path, calibrated: tuple[Path, Path, magfit.Calibration], short_pipe_wait: None
) -> None:
    data, saved, _ = calibrated
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    _error(_within(30, lambda: _run("apply", saved, data, "-o", fifo)), 2, "named pipe", "reader")
    _error(_within(30, lambda: _run("calibrate", data, "-m", "ellipsoid", "-o", fifo)), 2, "named pipe", "reader")
    # A reader that comes a little late still gets the rows.
    received: list[bytes] = []
    reader = threading.Timer(0.1, lambda: received.append(fifo.read_bytes()))
    reader.start()
    result = _within(30, lambda: _run("apply", saved, data, "-o", fifo))
    reader.join(5)
    assert result.exit_code == 0, result.output
    assert received[0].count(b"\n") == 501


@needs_fifo
def test_a_fifo_calibration_without_a_writer_is_refused_in_time(
    tmp_path: Path, calibrated: tuple[Path, Path, magfit.Calibration], short_pipe_wait: None
) -> None:
    data, saved, calibration = calibrated
    fifo = tmp_path / "cal.fifo"
    os.mkfifo(fifo)
    out = tmp_path / "o.csv"
    _error(_within(30, lambda: _run("apply", fifo, data, "-o", out)), 2, "cal.fifo", "named pipe")
    assert not out.exists()
    writer = threading.Thread(target=lambda: fifo.write_text(saved.read_text()), daemon=True)
    writer.start()
    result = _within(30, lambda: _run("apply", fifo, data, "-o", out))
    assert result.exit_code == 0, result.output
    raw = np.loadtxt(data, delimiter=",", skiprows=1)
    np.testing.assert_allclose(np.loadtxt(out, delimiter=",", skiprows=1), calibration.apply(raw), rtol=1e-8)


# ---------------------------------------------------------------------- damaged compressed files


@pytest.mark.parametrize(
    ("suffix", "magic"),
    [(".zst", b"\x28\xb5\x2f\xfd"), (".gz", b"\x1f\x8b\x08\x00"), (".xz", b"\xfd7zXZ\x00"), (".bz2", b"BZh9")],
)
def test_a_compressed_file_with_junk_after_its_magic_is_an_input_error(
    suffix: str, magic: bytes, tmp_path: Path
) -> None:
    if suffix == ".zst":
        pytest.importorskip("zstandard")
    path = tmp_path / f"s.csv{suffix}"
    path.write_bytes(magic + b"junk" * 20)
    for command in ("calibrate", "inspect", "compare"):
        _error(_run(command, path), 2, str(path), "damaged")


# ---------------------------------------------------------------------- calibrations that read back unusable


def _mutated(calibration: magfit.Calibration, **fields: Any) -> str:
    data = calibration.to_dict()
    data.update(fields)
    return json.dumps(data)


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        ("matrix", [[1.0, 1e308, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "'matrix' is not a usable correction"),
        ("matrix", [[1e308, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-300]], "'matrix' is not a usable correction"),
        ("matrix", [[1, 10**20, 0], [0, 1, 0], [0, 0, 1]], "'matrix' is not a usable correction"),  # det 1, cond 1e40
        ("offset", [1e200, 0.0, 0.0], "'offset'"),
    ],
)
def test_from_json_refuses_a_calibration_whose_products_leave_float64(
    field: str, value: Any, fragment: str, tmp_path: Path, calibrated: tuple[Path, Path, magfit.Calibration]
) -> None:
    data, _, calibration = calibrated
    text = _mutated(calibration, **{field: value})
    with pytest.raises(magfit.DataFileError, match=fragment):
        magfit.Calibration.from_json(text)
    for frame in ("sensor", "vehicle"):
        with pytest.raises(magfit.DataFileError, match=fragment):
            magfit.Calibration.from_json(_mutated(calibration, **{field: value, "frame": frame}))
    saved = tmp_path / "bad.json"
    saved.write_text(text)
    out = tmp_path / "o.csv"
    _error(_run("apply", saved, data, "-o", out), 2, "bad.json", fragment)
    assert not out.exists()  # no inf rows written


def test_from_json_refuses_a_number_beyond_float64_in_details(
    calibrated: tuple[Path, Path, magfit.Calibration],
) -> None:
    _, _, calibration = calibrated
    text = _mutated(calibration, details={"options": {"tolerance": 7.654321}, "x": [1, {"y": 0.123456}]})
    assert magfit.Calibration.from_json(text).details["x"][1]["y"] == 0.123456
    with pytest.raises(magfit.DataFileError, match=r"'details\.x\[1\]\.y' is inf"):
        magfit.Calibration.from_json(text.replace("0.123456", "1e999"))
    with pytest.raises(magfit.DataFileError, match=r"'details\.options\.tolerance' is -inf"):
        magfit.Calibration.from_json(text.replace("7.654321", "-1e999"))


def test_from_json_still_reads_every_calibration_magfit_writes() -> None:
    samples = magfit.scenario("mpu9250", "none").simulate(2000, seed=3).samples
    for method in ("ellipsoid", "sphere", "diag", "minmax", "als", "ml"):
        calibration = magfit.fit(samples, method=method, allow_undetermined=True)
        assert magfit.Calibration.from_json(calibration.to_json()) == calibration
    mirror = magfit.Calibration("vector", np.zeros(3), np.diag([1.0, 1.0, -1.0]), 50.0, frame="vehicle")
    assert magfit.Calibration.from_json(mirror.to_json()) == mirror  # a left-handed sensor's alignment


# ---------------------------------------------------------------------- a reader that closes standard output


MAIN = "import sys; from magfit.cli import main; sys.exit(main())"


@pytest.mark.slow
def test_apply_to_stdout_whose_reader_stops_ends_quietly(tmp_path: Path) -> None:
    import subprocess
    import sys

    samples = _samples(200_000)
    data = _csv(tmp_path / "big.csv", samples)
    saved = tmp_path / "cal.json"
    saved.write_text(magfit.fit(samples[:2000], method="ellipsoid", diagnostics=False).to_json())
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen(
        [sys.executable, "-c", MAIN, "apply", str(saved), str(data), "-o", "-"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    assert process.stdout is not None and process.stderr is not None
    first = process.stdout.readline()  # as head -1 does: one line, then the pipe is closed
    process.stdout.close()
    status = process.wait(timeout=120)
    stderr = process.stderr.read().decode()
    assert first == b"mx,my,mz\n"
    assert status in (0, 141), stderr
    assert "error" not in stderr and "Broken pipe" not in stderr and "Traceback" not in stderr, stderr


# ---------------------------------------------------------------------- an .npz with several (N, 3) arrays


@pytest.mark.parametrize("names", [("samples", "mag_cal"), ("accel", "mag"), ("arr_0", "arr_1")])
def test_an_npz_with_two_triples_is_refused_like_a_csv_with_two(names: tuple[str, str], tmp_path: Path) -> None:
    samples = _samples()
    other = samples * 0.5 + 3.0
    path = tmp_path / "two.npz"
    np.savez(path, **{names[0]: samples, names[1]: other})
    for command in ("calibrate", "compare"):
        _error(_run(command, path), 2, "several (N, 3) arrays", names[0], names[1], f"--columns {names[0]}")
    with pytest.raises(magfit.DataFileError, match=rf"columns=\['{names[0]}'\]"):
        magfit.io.read_samples(path)
    # The way out the message gives: each array, chosen by name, is read as it is.
    for name, expected in zip(names, (samples, other), strict=True):
        np.testing.assert_array_equal(magfit.io.read_samples(path, columns=[name]).samples, expected)
        result = _run("calibrate", path, "--columns", name, "-m", "ellipsoid", "-o", tmp_path / f"{name}.json")
        assert result.exit_code == 0, result.output
        fitted = magfit.Calibration.from_json((tmp_path / f"{name}.json").read_text())
        truth = magfit.fit(expected, method="ellipsoid", diagnostics=False)
        np.testing.assert_allclose(fitted.offset, truth.offset, rtol=1e-9, atol=1e-9)
    # A text file with two magnetometer triples is refused the same way.
    text = tmp_path / "two.csv"
    np.savetxt(text, np.column_stack([samples, other]), delimiter=",", comments="",
               header="mag_x,mag_y,mag_z,mag2_x,mag2_y,mag2_z")  # fmt: skip
    _error(_run("calibrate", text), 2)


# ---------------------------------------------------------------------- live: a glitched line, a full disk, a cut row

OFFSET = np.array([10.0, -5.0, 20.0])


def _uni_lines(n: int = 1500, glitch_at: int | None = 700) -> tuple[str, np.ndarray]:
    """``Uni:`` lines of a sphere of 48 µT around OFFSET, one with a magnetometer value of 3e200 at ``glitch_at``."""
    samples = magfit.simulate(n, field_strength=48.0, seed=1).samples + OFFSET
    lines = [f"Uni:0.1,0.2,9.8,0,0,0,{x:.4f},{y:.4f},{z:.4f}" for x, y, z in samples]
    if glitch_at is not None:
        lines.insert(glitch_at, "Uni:0.1,0.2,9.8,0,0,0,3e200,1,1")
    return "\r\n".join(lines) + "\r\n", samples


def test_a_uni_line_beyond_1e150_is_skipped_and_counted_by_the_parser() -> None:
    from magfit.live import LineParser

    text, samples = _uni_lines()
    parser = LineParser()
    rows = parser.feed(text.encode())
    assert parser.counts.samples == 1500 and parser.counts.junk == 1
    assert "3e200" in parser.counts.junk_examples[0]
    np.testing.assert_allclose(rows, np.round(samples, 4), atol=1e-9)


def test_live_with_a_glitched_line_calibrates_and_its_recording_too(tmp_path: Path) -> None:
    text, _ = _uni_lines()
    stream = tmp_path / "uni.txt"
    stream.write_text(text)
    output, record = tmp_path / "cal.json", tmp_path / "rec.csv"
    result = _within(120, lambda: _run("live", stream, "-o", output, "--record", record))
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    np.testing.assert_allclose(calibration.offset, OFFSET, atol=0.05)  # the truth, to the 4 decimals printed
    assert abs(calibration.field_strength - 48.0) < 0.05
    assert len(record.read_text().splitlines()) == 1 + 1500  # the glitched line is not recorded
    # A recording that holds such a row (written before the parser skipped them): skipped with a count.
    lines = record.read_text().splitlines()
    lines.insert(701, "0.500,3e+200,1,1")
    old = tmp_path / "old.csv"
    old.write_text("\n".join(lines) + "\n")
    result = _run("calibrate", old, "-m", "sphere", "-o", tmp_path / "old.json")
    assert result.exit_code == 0, result.output
    assert "skipped 1 of 1501 rows" in result.stderr and "(lines 702)" in result.stderr
    fitted = magfit.Calibration.from_json((tmp_path / "old.json").read_text())
    np.testing.assert_allclose(fitted.offset, OFFSET, atol=0.05)
    _error(_run("calibrate", old, "--nonfinite", "error"), 2, "line 702", "3e+200")


def test_a_full_disk_during_record_leaves_whole_rows(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    from magfit.live import record as record_module
    from magfit.live.record import Recorder

    path = tmp_path / "rec.csv"
    recorder = Recorder(path)
    samples = magfit.simulate(300, field_strength=48.0, seed=2).samples + OFFSET
    recorder.write(samples[:100], "uT")
    real_write = os.write
    calls = {"n": 0}

    def full_disk(descriptor: int, data: bytes) -> int:
        calls["n"] += 1
        if calls["n"] == 1:
            return real_write(descriptor, data[: len(data) // 2 + 7])  # the disk takes part of the batch ...
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # ... then refuses the rest

    monkeypatch.setattr(record_module.os, "write", full_disk)
    with pytest.raises(magfit.DataFileError, match="keeps the 100 whole rows"):
        recorder.write(samples[100:], "uT")
    monkeypatch.setattr(record_module.os, "write", real_write)
    recorder.close()
    text = path.read_text()
    assert text.endswith("\n") and len(text.splitlines()) == 101  # the header and the first batch, whole
    np.testing.assert_allclose(np.loadtxt(path, delimiter=",", skiprows=1)[:, 1:], samples[:100], rtol=1e-9)


def test_a_recording_whose_last_row_is_cut_is_read_without_it(tmp_path: Path) -> None:
    samples = magfit.simulate(2000, field_strength=48.0, seed=4).samples + OFFSET
    whole = tmp_path / "whole.csv"
    np.savetxt(whole, np.column_stack([np.arange(2000) * 0.01, samples]), fmt="%.10g", delimiter=",",
               header="time_s,mx(uT),my(uT),mz(uT)", comments="")  # fmt: skip
    cut = tmp_path / "cut.csv"
    cut.write_bytes(whole.read_bytes() + b"20.000,51.2345,-3.1")  # a row cut by a full disk or a power cut
    table = magfit.io.read_samples(cut)
    assert table.n_rows == 2001 and table.n_skipped == 1 and table.skipped_lines == (2002,)
    np.testing.assert_array_equal(table.samples, magfit.io.read_samples(whole).samples)
    result = _run("calibrate", cut, "-m", "sphere", "-o", tmp_path / "cal.json")
    assert result.exit_code == 0, result.output
    assert "skipped 1 of 2001 rows" in result.stderr and "cut short" in result.stderr
    fitted = magfit.Calibration.from_json((tmp_path / "cal.json").read_text())
    np.testing.assert_allclose(fitted.offset, OFFSET, atol=1e-3)
    _error(_run("calibrate", cut, "--nonfinite", "error"), 2, "line 2002 is cut short")
    # A last line with too many fields, or a cut line inside the file, is still refused.
    (tmp_path / "long.csv").write_bytes(whole.read_bytes() + b"20.000,1,2,3,4")
    _error(_run("calibrate", tmp_path / "long.csv"), 2, "line 2002 has 5 fields")
    lines = whole.read_text().splitlines()
    lines[10] = "0.09,51.2"
    (tmp_path / "inside.csv").write_text("\n".join(lines) + "\n")
    _error(_run("calibrate", tmp_path / "inside.csv"), 2, "line 11 has 2 fields")


# ---------------------------------------------------------------------- decompression bombs


def _gzip_bomb(path: Path, rows: int) -> Path:
    import gzip

    with gzip.open(path, "wb", compresslevel=9) as handle:
        handle.write(b"mx,my,mz\n")
        block = b"1,2,3\n" * 100_000
        for _ in range(rows // 100_000):
            handle.write(block)
    return path


def _peak_bytes(call: Callable[[], Any]) -> tuple[Any, int]:
    import tracemalloc

    tracemalloc.start()
    try:
        result = call()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_a_gzip_bomb_is_refused_within_bounded_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The campaign's bomb was 350 KB expanding to 40 million rows (85 s, 2.1 GB); this one is 2 million rows
    # (12 MB from 17 KB), against a floor lowered from 64 MB to 1 MB.
    bomb = _gzip_bomb(tmp_path / "bomb.csv.gz", 2_000_000)
    assert bomb.stat().st_size < 40_000
    monkeypatch.setattr(sources, "EXPANSION_FLOOR", 1 << 20)
    for command in ("calibrate", "compare", "inspect"):
        result, peak = _peak_bytes(lambda command=command: _run(command, bomb))
        _error(result, 2, "bomb.csv.gz", "expands to more than 1.67 MB", "decompression bomb")
        assert peak < 8 << 20, f"{command}: {peak / 2**20:.0f} MB traced"  # reading it whole took 48 MB and more
    sources._forget_all()
    with pytest.raises(magfit.DataFileError, match="decompression bomb"):
        magfit.io.read_samples(bomb)
    # A genuine compressed recording (a few times smaller than its text) is read as before.
    samples = _samples(100_000)
    plain = _csv(tmp_path / "s.csv", samples)
    import gzip

    packed = tmp_path / "s.csv.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    assert plain.stat().st_size > (1 << 20) and packed.stat().st_size * MAX_RATIO_OF_REAL_DATA > plain.stat().st_size
    np.testing.assert_allclose(magfit.io.read_samples(packed).samples, samples, rtol=1e-9)


MAX_RATIO_OF_REAL_DATA = 5  # simulated MPU-9250 counts compress about 3 times


def test_an_npz_bomb_is_refused_before_a_member_is_inflated(
    tmp_path: Path, calibrated: tuple[Path, Path, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    # The campaign's: 467 KB, one (20 000 000, 3) array of zeros; apply peaked at 3.5 GB. This one is 2 million
    # rows (46 MB from 45 KB; the floor lowered from 64 MB to 1 MB), refused from the zip header, not inflated.
    monkeypatch.setattr(sources, "EXPANSION_FLOOR", 1 << 20)
    _, saved, _ = calibrated
    bomb = tmp_path / "bomb.npz"
    np.savez_compressed(bomb, mag=np.zeros((2_000_000, 3)))
    assert bomb.stat().st_size < 100_000
    out = tmp_path / "out.npz"
    result, peak = _peak_bytes(lambda: _run("apply", saved, bomb, "-o", out))
    _error(result, 2, "bomb.npz", "member 'mag' expands to 45.8 MB", "decompression bomb")
    assert peak < 8 << 20 and not out.exists()
    for command in ("calibrate", "compare"):
        _error(_run(command, bomb), 2, "decompression bomb")
    # An npz of real samples (compressed or not) is read as before.
    samples = _samples(50_000)
    np.savez_compressed(tmp_path / "real.npz", mag=samples)
    np.testing.assert_array_equal(magfit.io.read_samples(tmp_path / "real.npz").samples, samples)


@pytest.mark.parametrize("layout", ["matrix", "vectors"])
@pytest.mark.slow
def test_apply_to_an_npz_streams_it(layout: str, tmp_path: Path) -> None:
    # apply loaded every array of an .npz whole (and copied them): 529 MB traced for 96 MB of arrays.
    samples = np.tile(_samples(500), (6000, 1))  # 3 million rows
    time_s = np.arange(len(samples)) * 0.01
    arrays = {"mag": samples} if layout == "matrix" else {f"mag_{a}": samples[:, i] for i, a in enumerate("xyz")}
    path = tmp_path / "big.npz"
    np.savez(path, **arrays, t=time_s)
    calibration = magfit.fit(samples[:500], method="ellipsoid", diagnostics=False)
    out = tmp_path / "out.npz"
    _, peak = _peak_bytes(lambda: magfit.io.write_calibrated(path, calibration, out))
    whole = samples.nbytes + time_s.nbytes
    assert peak < 2 * whole, f"{peak / 2**20:.0f} MB traced for {whole / 2**20:.0f} MB of arrays"
    with np.load(out) as written:
        assert list(written.files) == [*arrays, "t"]
        np.testing.assert_array_equal(written["t"], time_s)  # the other members, byte for byte
        corrected = (
            written["mag"] if layout == "matrix" else np.column_stack([written[f"mag_{a}"] for a in "xyz"])
        )
    np.testing.assert_allclose(corrected[:500], calibration.apply(samples[:500]), rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(corrected[-500:], corrected[:500])


@pytest.mark.external
@pytest.mark.parametrize("command", ["calibrate", "inspect"])
def test_a_command_printing_to_a_closed_pipe_exits_141(tmp_path: Path, command: str) -> None:
    """rich's console exits 1 on a closed standard output by itself ("the data cannot support the fit"); magfit's
    ends as every other closed pipe does: quietly, 141."""
    import subprocess
    import sys

    data = _csv(tmp_path / "small.csv", _samples(2000))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen(
        [sys.executable, "-c", MAIN, command, str(data)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env
    )
    assert process.stdout is not None and process.stderr is not None
    process.stdout.close()  # as `| true` does: nobody reads
    status = process.wait(timeout=120)
    stderr = process.stderr.read().decode()
    assert status == 141, stderr
    assert "Traceback" not in stderr, stderr
