"""The CSV reader in chunks (issue 17): the same samples whatever the chunking or the
compression, errors naming the right line in any chunk, magnitudes no fit can square refused."""

from __future__ import annotations

import bz2
import gzip
import lzma
import warnings

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


def test_an_error_after_blank_lines_names_the_line_of_the_file(tmp_path):
    lines = frame(10)[["mx", "my", "mz"]].to_csv(index=False).splitlines()
    lines[6] = "1.0,oops,2.0"                      # data row 6, line 7 before the blanks
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(lines[:3] + ["", "   "] + lines[3:]) + "\n")
    with pytest.raises(ValueError, match=r"non-numeric value 'oops' in column 'my' at data row "
                                         r"6 \(line 9 of the file\)"):
        read_samples(path, check=False)


def test_leading_comment_lines_are_notes_and_still_count_as_lines(tmp_path):
    """A logger's '#' lines before the table (device, date) are skipped; an error names the
    line of the file, counting them."""
    table = frame(50)[["mx", "my", "mz"]]
    lines = table.to_csv(index=False).splitlines()
    path = tmp_path / "rec.csv"
    path.write_text("# logger v2, 2026-11-24\n#   sensor: QMC5883L\n" + "\n".join(lines) + "\n")
    rec = read_samples(path, check=False)
    np.testing.assert_allclose(rec.y, table.to_numpy(), rtol=1e-12)
    lines[4] = "1.0,oops,2.0"                      # data row 4: line 8 after 3 lines of notes
    path.write_text("# logger v2\n\n# sensor\n" + "\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"non-numeric value 'oops' in column 'my' at data row "
                                         r"4 \(line 8 of the file\)"):
        read_samples(path, check=False)


def two_compasses(tmp_path, column="I"):
    a, b = frame(40), frame(40) * 1.5
    a.insert(0, column, 0)
    b.insert(0, column, 1)
    path = tmp_path / "mag.csv"
    pd.concat([a, b]).sort_values("t", kind="stable").to_csv(path, index=False)
    return path, a, b


@pytest.mark.parametrize("column", ["I", "instance", "device_id"])
def test_several_sensors_are_refused_naming_them_and_one_is_chosen(tmp_path, column):
    path, a, b = two_compasses(tmp_path, column)
    with pytest.raises(ValueError, match=rf"holds 2 sensors in column '{column}': 0 \(40 rows\), "
                                         r"1 \(40 rows\); choose one with instance=, e\.g\. "
                                         r"instance=0"):
        read_samples(path, check=False)
    for value, part in ((1, b), ("1.0", b), ("0", a)):
        rec = read_samples(path, check=False, instance=value)
        np.testing.assert_array_equal(rec.y, part[["mx", "my", "mz"]].to_numpy())
        np.testing.assert_array_equal(rec.t, part["t"].to_numpy())
        assert rec.instance[0] == column
    with pytest.raises(ValueError, match=rf"instance=7 is not in column '{column}'.*0 \(40 rows\)"):
        read_samples(path, check=False, instance=7)


def test_instance_without_an_instance_column_is_refused(tmp_path):
    path = tmp_path / "rec.csv"
    frame()[["mx", "my", "mz"]].to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"instance=1 was given but rec\.csv has no instance "
                                         r"column"):
        read_samples(path, check=False, instance=1)
    assert read_samples(path, check=False).instance is None


def test_iso_times_are_read_as_seconds_from_the_first(tmp_path):
    data = frame(20)
    start = pd.Timestamp("2025-03-01T12:00:00Z")
    data["t"] = [(start + pd.Timedelta(seconds=0.05 * i)).isoformat() for i in range(20)]
    path = tmp_path / "rec.csv"
    data.to_csv(path, index=False)
    rec = read_samples(path, check=False)
    np.testing.assert_allclose(rec.t, 0.05 * np.arange(20), atol=1e-9)
    assert rec.has_gyro


def test_a_time_column_of_text_is_dropped_with_a_warning(tmp_path):
    data = frame(20)
    data["t"] = "soon"
    path = tmp_path / "rec.csv"
    data.to_csv(path, index=False)
    with pytest.warns(UserWarning, match=r"column 't' holds neither seconds nor ISO 8601 times "
                                         r"\(e\.g\. 'soon' on line 2\); reading without times, "
                                         r"so the gyro columns are not used"):
        rec = read_samples(path, check=False)
    assert rec.t is None and rec.gyro is None and rec.K == 20


@pytest.mark.parametrize("sep", [";", "\t", " "])
def test_decimal_commas_are_read_when_columns_are_not_comma_separated(tmp_path, sep):
    data = frame(12)
    path = tmp_path / "rec.csv"
    data.to_csv(path, index=False, sep=sep, decimal=",")
    rec = read_samples(path, check=False)
    np.testing.assert_allclose(rec.y, data[["mx", "my", "mz"]].to_numpy(), rtol=1e-15)
    np.testing.assert_allclose(rec.t, data["t"].to_numpy())


def test_a_decimal_comma_in_a_comma_separated_file_is_named(tmp_path):
    path = tmp_path / "rec.csv"
    path.write_text('mx,my,mz\n1.5,2,3\n"1,5",2,3\n')
    with pytest.raises(ValueError, match=r"'1,5' in column 'mx' at data row 2 \(line 3 of the "
                                         r"file\); it looks like a decimal comma"):
        read_samples(path, min_samples=1, check=False)


@pytest.mark.parametrize(("text", "message"), [
    ("x y z\n0 1 2 3 4 5\n1 2 3 4 5 6\n",
     r"^f\.txt: the header names 3 columns but line 2 has 6 fields; name every column"),
    ("0 1 2 3 4 5\n1 2 3 4 5 6\n\n2 3 4 5 6 7 8\n",
     r"^f\.txt: line 4 has 7 fields where the rows before have 6"),
    ("0 1 2\n1 2 3\n", r"^columns positions \[3, 4, 5\] are out of range; the file has 3 columns"),
])
def test_a_text_dump_with_columns_by_position_gets_one_line(tmp_path, text, message):
    path = tmp_path / "f.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as caught:
        read_samples(path, [3, 4, 5], min_samples=1, check=False)
    assert "\n" not in str(caught.value)


def test_an_unclosed_quote_names_its_line(tmp_path):
    lines = frame(10)[["mx", "my", "mz"]].to_csv(index=False).splitlines()
    lines[4] = '"' + lines[4]
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"^rec\.csv: a quoted field opens on line 5 and is "
                                         r"never closed"):
        read_samples(path, check=False)


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


_ROWS = [[0.0, 6202, 682.5, -4812], [0.02, 1 / 3, 2.5e-7, 1e5], [0.04, -0.0, 17.0, 3.25]]
_PLAIN = "t,mx,my,mz,gx,gy,gz,qw\n" + "".join(
    f"{t!r},{x!r},{y!r},{z!r},0.1,-0.2,{0.3 * i!r},{'nan' if i else 1.0}\n"
    for i, (t, x, y, z) in enumerate(_ROWS * 4))


@pytest.mark.parametrize(("text", "by_numpy"), [
    (_PLAIN, True),
    (_PLAIN.replace("\n", "\r\n"), True),                        # Windows line ends
    (_PLAIN.replace("0.1,", " 0.1 ,"), True),                    # padded numbers
    (_PLAIN.replace("0.04,", "NaN,", 1).replace(",nan\n", ",NAN\n", 1), True),
    (_PLAIN.replace("\n0.02,", "\n\n0.02,", 1), True),           # a blank line
    (_PLAIN.replace(",", ";"), True),
    (_PLAIN.replace("t,mx", "t , mx"), True),                   # padded names
    (_PLAIN.split("\n", 1)[1], True),                           # no header: by position
    (_PLAIN.replace("0.04,", "inf,", 1), False),                # pandas' own spellings
    (_PLAIN.replace("0.04,", "-nan,", 1), False),
    (_PLAIN.replace("0.04,", "NA,", 1), False),
    (_PLAIN.replace("0.04,", ",", 1), False),                   # an empty cell
    (_PLAIN.replace("0.04,", '"0.04",', 1), False),
    (_PLAIN.replace("\n0.02,", "\n  \n0.02,", 1), False),
    (_PLAIN.replace("0.1,-0.2", "0.1,x", 1), False),
    (_PLAIN.replace("t,mx,my", "t,mx,mx", 1), False),           # duplicate names
    (_PLAIN.replace(",qw\n", ",qw,extra\n", 1), False),         # a header wider than rows
    ("# logger notes\n" + _PLAIN, False),
])
def test_numpy_reads_a_plain_file_as_pandas_does(tmp_path, monkeypatch, text, by_numpy):
    # The pandas-free reader takes only what both parsers read alike: the same samples,
    # columns and warnings (or the same error) either way.
    path = tmp_path / "rec.csv"
    path.write_bytes(text.encode())
    columns = None if text.startswith("t") else [1, 2, 3]
    used = []
    plain = recordings._plain_table
    monkeypatch.setattr(recordings, "_plain_table",
                        lambda *a: used.append(plain(*a) is not None) or plain(*a))

    def read():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                rec = read_samples(path, columns, check=False)
            except ValueError as exc:
                return str(exc), []
        return rec, [str(w.message) for w in caught]

    fast, fast_warnings = read()
    monkeypatch.setattr(recordings, "PLAIN_MAX_BYTES", -1)
    slow, slow_warnings = read()
    assert (used[:1] == [True]) is by_numpy and True not in used[1:]
    assert fast_warnings == slow_warnings
    if isinstance(slow, str):
        assert fast == slow
        return
    for name in ("y", "t", "gyro"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name))
        # The same memory layout too: NumPy and BLAS may sum in another order over another.
        assert getattr(getattr(fast, name), "strides", None) == \
            getattr(getattr(slow, name), "strides", None)
    assert (fast.columns, fast.n_rows, list(fast.extra or {})) == \
        (slow.columns, slow.n_rows, list(slow.extra or {}))
    for name, values in (slow.extra or {}).items():
        np.testing.assert_array_equal(fast.extra[name], values)


# --- the axes as phones' apps and loggers name them ---------------------------------------

def _write_named(path, header, sep, y, t=None, extra=None):
    rows = [([] if t is None else [t[k]]) + list(y[k]) + ([] if extra is None else [extra[k]])
            for k in range(len(y))]
    path.write_text(sep.join(header) + "\n" + "\n".join(sep.join(f"{v:.9e}" for v in r)
                                                         for r in rows) + "\n",
                    encoding="utf-8")
    return path


@pytest.mark.parametrize("header, sep", [
    (['"Time (s)"', '"Magnetic field x (µT)"', '"Magnetic field y (µT)"',
      '"Magnetic field z (µT)"', '"Absolute field (µT)"'], ","),
    (["Time (s)", "MAGNETIC FIELD X (\u03bcT)", "MAGNETIC FIELD Y (\u03bcT)",
      "MAGNETIC FIELD Z (\u03bcT)", "B (\u03bcT)"], ";"),
    (["t [s]", "mag_x [mG]", "mag_y [mG]", "mag_z [mG]", "temperature"], "\t"),
])
def test_axes_named_with_units_and_words_are_found(tmp_path, header, sep):
    y = frame()[["mx", "my", "mz"]].to_numpy()
    t = np.arange(len(y)) * 0.02
    path = _write_named(tmp_path / "phone.csv", header, sep, y, t, np.linalg.norm(y, axis=1))
    rec = read_samples(path)
    np.testing.assert_allclose(rec.y, y, rtol=1e-9)
    np.testing.assert_allclose(rec.t, t, atol=1e-12)
    assert [c.strip('"') for c in rec.columns] == [h.strip('"') for h in header[1:4]]


def test_axis_names_in_another_order_are_put_in_axis_order(tmp_path):
    y = frame()[["mx", "my", "mz"]].to_numpy()
    path = _write_named(tmp_path / "logger.csv", ["z", "y", "x"], ",", y[:, ::-1])
    np.testing.assert_allclose(read_samples(path).y, y, rtol=1e-9)


@pytest.mark.parametrize("header, why", [
    (["t", "x (m)", "y (m)", "z (m)"], "positions in metres are not a field"),
    (["gyro x", "gyro y", "gyro z", "t"], "no magnetic word"),
])
def test_columns_that_are_not_one_magnetometer_are_not_guessed(tmp_path, header, why):
    y = frame()[["mx", "my", "mz"]].to_numpy()
    path = _write_named(tmp_path / "other.csv", header, ",", y, extra=y[:, 0])
    with pytest.raises(ValueError, match="cannot tell which columns hold the magnetometer"):
        read_samples(path)


def test_two_magnetometers_in_one_file_are_not_guessed(tmp_path):
    y = frame()[["mx", "my", "mz"]].to_numpy()
    header = ["mag_x_cal", "mag_y_cal", "mag_z_cal", "mag_x_raw", "mag_y_raw", "mag_z_raw"]
    path = tmp_path / "two.csv"
    path.write_text(",".join(header) + "\n" + "\n".join(
        ",".join(f"{v:.6f}" for v in [*r, *(r + 1.0)]) for r in y) + "\n")
    with pytest.raises(ValueError, match="cannot tell which columns"):
        read_samples(path)
