"""magfit.io on every file of ../shared/data/real: which columns are picked, how many rows, the first sample.

Each recording loads with no hint, except the MXL file that holds two magnetometers (an ambiguity error
without ``columns``). The first sample is checked against the file's first data line as printed by
``head``, so a shifted column or a skipped preamble line cannot pass unnoticed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magfit import DataFileError
from magfit.io import iter_sample_chunks, read_samples

# file, columns hint, columns picked, rows, delimiter, first sample (x, y, z) as in the file
RECORDINGS = [
    ("fxos8700_magneto/mag-readings.txt", None, ("column 1", "column 2", "column 3"), 324, "\t",
     (28.0, -22.800001, -79.400001)),
    ("unc_qmc5883l/filtered_raw_data.csv", None, ("mx", "my", "mz"), 22745, ",", (6202, 682, 4812)),
    ("betaflight_apex5_qmc5883/20231014_apex5_mag_on_tpu_03.txt", None, ("column 1", "column 2", "column 3"),
     6005, ", ", (1202, 281, -837)),
    ("betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt", None, ("column 1", "column 2", "column 3"),
     26407, ", ", (-413, 758, 318)),
    ("mxl_umich_mpu9250_rm3100/preflight_data_original.csv", ["mag_x", "mag_y", "mag_z"],
     ("mag_x", "mag_y", "mag_z"), 1264, ",", (-938, 840, -3642)),
    ("mxl_umich_mpu9250_rm3100/preflight_data_original.csv", ["imu_mx", "imu_my", "imu_mz"],
     ("imu_mx", "imu_my", "imu_mz"), 1264, ",", (55, 1, -153)),
    ("mxl_umich_mpu9250_rm3100/preflight_data_original_imu.csv", None, ("imu_mx", "imu_my", "imu_mz"), 1264, ",",
     (8.25, 0.15, -22.95)),
    ("mxl_umich_mpu9250_rm3100/preflight_data_original_pni.csv", None, ("mag_x", "mag_y", "mag_z"), 1264, ",",
     (-12.50666667, 11.2, -48.56)),
    ("mxl_umich_mpu9250_rm3100/test0_esti_trunc.csv", None, ("mag_x", "mag_y", "mag_z"), 4960, ",",
     (11.7733, -8.24, 48.9067)),
    # accelerometer ax_raw.. and the authors' min/max-calibrated m*_scaled are passed over for m*_raw
    ("animaltrack_missionbay/missionbay_calib2_converted.csv", None, ("mx_raw", "my_raw", "mz_raw"), 275, ",",
     (155, -9, -203)),
    ("animaltrack_missionbay/missionbay2_converted.csv", None, ("mx_raw", "my_raw", "mz_raw"), 4012, ",",
     (160, -64, -204)),
    # gyro Wx.. and accelerometer Ax.. are passed over
    ("gyrolib_rahrs/calibrationGyroLib_converted.csv", None, ("Mx", "My", "Mz"), 16314, ",", (-645, 710, -1966)),
    ("hamagure_gauss/data-set_1.csv", None, ("x", "y", "z"), 3000, ",",
     (-0.196280002593994, -0.0538999997079372, -0.919660031795502)),
    ("hamagure_gauss/data-set_2.csv", None, ("x", "y", "z"), 9765, ",", (-0.1726875, 0.1925625, -0.4430625)),
    ("ensta_tlefloch_imu/mag_data.txt", None, ("column 1", "column 2", "column 3"), 6121, "whitespace",
     (-0.011998045920859795, -0.7108842208109428, -0.701885686370298)),
    ("ensta_tlefloch_imu/raw_data.npz", None, ("mag_x", "mag_y", "mag_z"), 6121, None, None),
    # x, y, z then t (ms): t is left out
    ("android_phone_kritiksoman/data_mag.txt", None, ("x", "y", "z"), 1266, ",", (34.3125, 44.0625, 420.3125)),
    # the phone's accelerometer, in the same x,y,z,t layout: it loads (the names cannot tell it apart)
    ("android_phone_kritiksoman/data_acc.txt", None, ("x", "y", "z"), 2533, ",", (0.001952, -0.211792, 0.835944)),
    ("hmc5883l_nliaudat_partial/mag_out_sample.txt", None, ("column 1", "column 2", "column 3"), 243, ",",
     (33.1, 98.3, 571.2)),
]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "hint", "picked", "n_rows", "delimiter", "first"), RECORDINGS, ids=[r[0] for r in RECORDINGS]
)
def test_every_recording_loads(real_data_dir: Path, name, hint, picked, n_rows, delimiter, first) -> None:
    table = read_samples(real_data_dir / name, columns=hint)
    assert table.columns == picked
    assert (table.n_rows, table.n_skipped, table.samples.shape) == (n_rows, 0, (n_rows, 3))
    assert table.format.delimiter == delimiter
    if first is not None:
        np.testing.assert_array_equal(table.samples[0], first)
    assert np.all(np.ptp(table.samples, axis=0) > 0)  # three real, varying columns


def test_the_npz_and_the_text_export_of_the_ensta_imu_agree(real_data_dir: Path) -> None:
    npz = read_samples(real_data_dir / "ensta_tlefloch_imu" / "raw_data.npz")
    text = read_samples(real_data_dir / "ensta_tlefloch_imu" / "mag_data.txt")
    np.testing.assert_allclose(npz.samples, text.samples, rtol=1e-15)


def test_layouts_found(real_data_dir: Path) -> None:
    unc = read_samples(real_data_dir / "unc_qmc5883l" / "filtered_raw_data.csv").format
    assert (unc.preamble_lines, unc.header, unc.data_line) == (2, ("mx", "my", "mz"), 3)
    imu = read_samples(real_data_dir / "mxl_umich_mpu9250_rm3100" / "preflight_data_original_imu.csv").format
    assert imu.encoding == "utf-8-sig" and imu.header == ("imu_mx", "imu_my", "imu_mz")
    original = iter_sample_chunks(real_data_dir / "mxl_umich_mpu9250_rm3100" / "preflight_data_original.csv",
                                  columns=["mag_x", "mag_y", "mag_z"]).format  # fmt: skip
    assert original.n_columns == 30 and original.header[:3] == ("unix_time", "cur_time", "imu_ax")


def test_two_magnetometers_in_one_file_ask_for_columns(real_data_dir: Path) -> None:
    path = real_data_dir / "mxl_umich_mpu9250_rm3100" / "preflight_data_original.csv"
    with pytest.raises(DataFileError) as caught:
        read_samples(path)
    assert str(caught.value) == (
        f"{path}: several magnetometer column triples match: (imu_mx,imu_my,imu_mz); (mag_x,mag_y,mag_z); "
        "choose one with columns=['imu_mx', 'imu_my', 'imu_mz']"
    )


def test_chunks_of_the_largest_recording_equal_the_whole(real_data_dir: Path) -> None:
    path = real_data_dir / "betaflight_apex5_qmc5883" / "20231008_apex5_mag_on_tpu_00.txt"
    whole = read_samples(path).samples
    reader = iter_sample_chunks(path, chunk_rows=5000)
    chunks = list(reader)
    assert [len(c) for c in chunks] == [5000] * 5 + [1407] and reader.n_rows == 26407
    np.testing.assert_array_equal(np.concatenate(chunks), whole)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        # parameter files published beside the recordings: not samples, and said so
        ("gyrolib_rahrs/magn.coefs_converted.csv", "no magnetometer columns found among: V1, V2, V3"),
        ("unc_qmc5883l/paramters_mag.csv", "has 1 field per row"),
        ("mxl_umich_mpu9250_rm3100/test0_esti_trun_calibrationParamters.csv", "has 2 fields per row"),
        ("gyrolib_rahrs/calibrationGyroLib.RData", "is a binary file, not delimited text, .npy or .npz"),
    ],
)
def test_files_that_are_not_recordings_are_refused_clearly(real_data_dir: Path, name: str, message: str) -> None:
    with pytest.raises(DataFileError, match=message):
        read_samples(real_data_dir / name)
