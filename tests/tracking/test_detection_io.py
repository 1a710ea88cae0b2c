import numpy as np
import pytest

from spacetrack.tracking.io import DetectionFileError, iter_frames, load_detections, write_mot_results


def _dets(num_rows=4, dim=3):
    rows = np.zeros((num_rows, 10 + dim))
    rows[:, 0] = np.arange(1, num_rows + 1)
    rows[:, 1] = rows[:, 7:10] = -1
    rows[:, 2:6] = [10, 20, 30, 40]
    rows[:, 6] = 0.9
    rows[:, 10:] = 1.0
    return rows


def _save(tmp_path, array, name="dets.npy"):
    path = tmp_path / name
    np.save(path, array)
    return path


def test_a_valid_file_loads_and_frames_include_gaps(tmp_path):
    dets = _dets()
    dets[2:, 0] = [5, 5]
    loaded = load_detections(_save(tmp_path, dets))
    np.testing.assert_array_equal(loaded, dets)
    frames = list(iter_frames(loaded))
    assert [f for f, _ in frames] == [1, 2, 3, 4, 5]
    assert [len(rows) for _, rows in frames] == [1, 1, 0, 0, 2]


def _corrupt(kind):
    dets = _dets()
    if kind == "nan":
        dets[2, 3] = np.nan
    elif kind == "inf":
        dets[1, 12] = np.inf
    elif kind == "zero_width":
        dets[3, 4] = 0.0
    elif kind == "negative_height":
        dets[1, 5] = -4.0
    elif kind == "out_of_order":
        dets[2, 0] = 1
    elif kind == "fractional_frame":
        dets[1, 0] = 2.5
    elif kind == "dimension_change":
        dets[2, 11:] = np.nan
    return dets


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        ("nan", "row 2, column 3 (y) is nan"),
        ("inf", "row 1, column 12 (feature[2]) is inf"),
        ("zero_width", "row 3, w = 0.0 is not positive"),
        ("negative_height", "row 1, h = -4.0 is not positive"),
        ("out_of_order", "row 2, frame 1 comes after frame 2"),
        ("fractional_frame", "row 1, frame 2.5 is not a whole number"),
        ("dimension_change", "row 2 has a 1-dim feature (NaN-padded) but the file is 3-dim"),
    ],
)
def test_bad_values_are_named_with_file_row_and_value(tmp_path, kind, message):
    path = _save(tmp_path, _corrupt(kind))
    with pytest.raises(DetectionFileError, match="dets.npy") as err:
        load_detections(path)
    assert message in str(err.value)


@pytest.mark.parametrize(
    ("array", "message"),
    [
        (np.zeros((3, 7)), "7 columns; expected at least 10"),
        (np.zeros((0, 12)), "empty (0 rows)"),
        (np.zeros(12), "array of shape (12,)"),
        (np.array([[1.0, 2.0], [3.0]], dtype=object), "object array"),
    ],
)
def test_bad_shapes_are_refused(tmp_path, array, message):
    path = _save(tmp_path, array)
    with pytest.raises(DetectionFileError) as err:
        load_detections(path)
    assert message in str(err.value) and str(path) in str(err.value)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.npy"):
        load_detections(tmp_path / "nope.npy")
    (tmp_path / "zero.npy").write_bytes(b"")
    with pytest.raises(DetectionFileError, match="zero.npy: empty file"):
        load_detections(tmp_path / "zero.npy")
    (tmp_path / "text.npy").write_text("frame,id\n")
    with pytest.raises(DetectionFileError, match="text.npy: not a readable .npy file"):
        load_detections(tmp_path / "text.npy")


def test_results_are_mot_rows(tmp_path):
    path = tmp_path / "out.txt"
    write_mot_results(path, np.array([[3, 7, 1.234, 2.0, 30.5, 40.0]]))
    assert path.read_text() == "3,7,1.23,2.00,30.50,40.00,1,-1,-1,-1\n"
