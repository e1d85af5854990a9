"""The CSV reader in chunks (issue 17): the same samples whatever the chunking or the
compression, errors naming the right line in any chunk, magnitudes no fit can square refused."""

from __future__ import annotations

import bz2
import gzip
import lzma

import numpy as np
import pandas as pd
import pytest

import magbench.sources.recordings as recordings
from magbench.core.geometry import fibonacci_sphere
from magbench.sources.recordings import read_samples


def frame(K: int = 50) -> pd.DataFrame:
    y = 40.0 * (fibonacci_sphere(K) * [1.1, 0.9, 1.0] + [0.2, -0.1, 0.05])
    out = pd.DataFrame(y, columns=["mx", "my", "mz"])
    out.insert(0, "t", np.arange(K) * 0.05)
    for i, axis in enumerate("xyz"):
        out[f"g{axis}"] = 0.1 * (i + 1) * np.sin(np.arange(K) / 7.0)
    return out


def test_chunks_give_the_same_samples_as_one_read(tmp_path, monkeypatch):
    data = frame()
    data.loc[7, "my"] = np.nan                     # a missing value, dropped either way
    path = tmp_path / "rec.csv"
    data.to_csv(path, index=False)
    whole = read_samples(path, check=False)
    monkeypatch.setattr(recordings, "CHUNK_ROWS", 6)
    with pytest.warns(UserWarning, match="dropped 1 of 50 rows"):
        chunked = read_samples(path, check=False)
    kept = data.drop(index=7)
    for rec in (whole, chunked):
        np.testing.assert_array_equal(rec.y, kept[["mx", "my", "mz"]].to_numpy())
        np.testing.assert_array_equal(rec.t, kept["t"].to_numpy())
        np.testing.assert_array_equal(rec.gyro, kept[["gx", "gy", "gz"]].to_numpy())


def test_padded_and_missing_cells_in_a_later_chunk(tmp_path, monkeypatch):
    lines = frame(30)[["mx", "my", "mz"]].to_csv(index=False).splitlines()
    lines[20] = " " + lines[20].replace(",", " , ")          # padded numbers are numbers
    lines[22] = "NA,1.0,2.0"                                 # a missing value
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(recordings, "CHUNK_ROWS", 8)
    with pytest.warns(UserWarning, match="dropped 1 of 30 rows"):
        rec = read_samples(path, check=False)
    assert rec.K == 29
    np.testing.assert_array_equal(rec.y[19], [float(v) for v in lines[20].split(",")])


def test_a_bad_cell_in_a_later_chunk_names_its_line(tmp_path, monkeypatch):
    lines = frame(30)[["mx", "my", "mz"]].to_csv(index=False).splitlines()
    fields = lines[25].split(",")                 # data row 25, line 26 of the file
    lines[25] = ",".join([fields[0], "12.3.4", fields[2]])
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(recordings, "CHUNK_ROWS", 8)
    with pytest.raises(ValueError, match=r"non-numeric value '12.3.4' in column 'my' at data "
                                         r"row 25 \(line 26 of the file\)"):
        read_samples(path, check=False)


@pytest.mark.parametrize(("suffix", "opener"), [(".csv.gz", gzip.open), (".csv", bz2.open),
                                                (".xz", lzma.open)])
def test_compressed_files_are_read_as_the_plain_one(tmp_path, suffix, opener):
    # Recognised by their first bytes, whatever the file is called.
    data = frame()
    plain = tmp_path / "plain.csv"
    data.to_csv(plain, index=False)
    packed = tmp_path / f"packed{suffix}"
    with opener(packed, "wt") as handle:
        data.to_csv(handle, index=False)
    a, b = read_samples(plain, check=False), read_samples(packed, check=False)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.gyro, b.gyro)


@pytest.mark.parametrize("scale", [1e151, 1e-153])
def test_magnitudes_no_fit_can_square_are_refused(tmp_path, scale):
    path = tmp_path / "rec.csv"
    (frame()[["mx", "my", "mz"]] * scale).to_csv(path, index=False)
    with pytest.raises(ValueError, match="outside the range magbench can calibrate"):
        read_samples(path)


def test_a_long_recording_keeps_every_sample(tmp_path, monkeypatch):
    # The geometry check looks at an even stride; the samples themselves are all kept.
    monkeypatch.setattr(recordings, "GEOMETRY_SAMPLES", 40)
    path = tmp_path / "rec.csv"
    frame(400)[["mx", "my", "mz"]].to_csv(path, index=False)
    assert read_samples(path).K == 400


def test_read_inertial_keeps_missing_attitude_and_drops_rows_without_samples(tmp_path):
    from magbench.sources.recordings import read_inertial

    path = tmp_path / "rec" / "data.csv"
    path.parent.mkdir()
    path.write_text("t,mx,my,mz,gx,gy,gz,ax,ay,az,qw,qx,qy,qz\n"
                    "0,1,2,3,0.1,0.2,0.3,0,0,9.8,nan,nan,nan,nan\n"
                    "0.1,,2,3,0.1,0.2,0.3,0,0,9.8,1,0,0,0\n"
                    "0.2,4,5,6,0.4,0.5,0.6,0,0,9.8,1,0,0,0\n")
    rec = read_inertial(path)
    assert rec.name == "rec" and rec.K == 2
    assert np.array_equal(rec.y, [[1, 2, 3], [4, 5, 6]])
    assert np.isnan(rec.attitude[0]).all() and np.array_equal(rec.attitude[1], [1, 0, 0, 0])
    assert rec.acceleration.shape == (2, 3) and rec.rows(slice(1, None)).K == 1
    bare = tmp_path / "bare.csv"
    bare.write_text("t,mx,my,mz\n0,1,2,3\n")
    assert read_inertial(bare).gyro is None
    (tmp_path / "bad.csv").write_text("mx,my,mz\n1,2,3\n")
    with pytest.raises(ValueError, match="needs columns t"):
        read_inertial(tmp_path / "bad.csv")
