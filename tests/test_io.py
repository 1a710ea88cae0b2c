"""Content hashes of files: what the caches and the weights records are keyed on."""

from __future__ import annotations

import hashlib

from spacetrack.io import file_hash, files_hash


def test_files_hash_follows_names_bytes_and_order_not_the_folder(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    for folder in (a, b):
        (folder / "000001.jpg").write_bytes(b"first frame")
        (folder / "000002.jpg").write_bytes(b"second frame")
    frames = ["000001.jpg", "000002.jpg"]
    same = files_hash([a / n for n in frames])
    assert same == files_hash([b / n for n in frames]) and same.startswith("sha256:")
    assert files_hash([a / n for n in reversed(frames)]) != same
    (b / "000002.jpg").write_bytes(b"second frame, rendered again")
    assert files_hash([b / n for n in frames]) != same
    # a missing file differs from an empty one, and both from the file not listed
    (a / "static.txt").write_bytes(b"")
    listed = [a / "000001.jpg", a / "static.txt"]
    empty = files_hash(listed)
    (a / "static.txt").unlink()
    assert len({empty, files_hash(listed), files_hash(listed[:1])}) == 3
    # the bytes of one file split differently between two names give another hash
    (a / "x").write_bytes(b"ab")
    (a / "y").write_bytes(b"c")
    (b / "x").write_bytes(b"a")
    (b / "y").write_bytes(b"bc")
    assert files_hash([a / "x", a / "y"]) != files_hash([b / "x", b / "y"])


def test_file_hash_is_the_sha256_of_the_bytes_alone(tmp_path):
    """Weights are named by it in recorded results and cache keys: it must not change with the folder."""
    path = tmp_path / "weights.pt"
    path.write_bytes(b"weights")
    assert file_hash(path) == "sha256:" + hashlib.sha256(b"weights").hexdigest()[:16]
