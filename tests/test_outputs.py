"""Atomic outputs: umask, symbolic links, existing modes, refused paths, nothing half-written."""

import json
import os
import stat

import pytest

from kpioed_drake.errors import InputError
from kpioed_drake.outputs import Outputs, atomic_write_json, atomic_write_text, check_output_paths


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_new_file_follows_umask(tmp_path, mask):
    old = os.umask(mask)
    try:
        atomic_write_text(tmp_path / "a.txt", "x\n")
    finally:
        os.umask(old)
    assert _mode(tmp_path / "a.txt") == 0o666 & ~mask
    assert (tmp_path / "a.txt").read_text() == "x\n"


def test_existing_file_keeps_its_mode(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    p.chmod(0o640)
    atomic_write_text(p, "new")
    assert _mode(p) == 0o640 and p.read_text() == "new"


def test_symlink_is_written_through(tmp_path):
    target = tmp_path / "real.json"
    target.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    atomic_write_json(link, {"a": 1})
    assert link.is_symlink()
    assert json.loads(target.read_text()) == {"a": 1}


def test_no_temporary_file_left_on_failure(tmp_path):
    with pytest.raises(TypeError):
        atomic_write_json(tmp_path / "a.json", {"a": object()})
    assert list(tmp_path.iterdir()) == []


def test_folder_as_output_is_refused(tmp_path):
    with pytest.raises(InputError, match="is a folder"):
        atomic_write_text(tmp_path, "x")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"inputs": ["{d}/in.csv"], "outputs": ["{d}/in.csv"]}, "overwrite the input"),
        ({"inputs": ["{d}/in.csv"], "outputs": ["{d}/./in.csv"]}, "overwrite the input"),
        ({"outputs": ["{d}/o.json", "{d}/o.json"]}, "named twice"),
        ({"outputs": ["{d}"]}, "is a folder"),
        ({"outputs": ["{d}/in.csv/x.json"]}, "is a file, not a folder"),
        ({"folders": ["{d}/in.csv"]}, "expected a folder"),
        ({"outputs": ["{d}/p.xyz"], "suffixes": {"{d}/p.xyz": (".png",)}}, r"\.png"),
    ],
)
def test_check_output_paths_refuses(tmp_path, kwargs, match):
    (tmp_path / "in.csv").write_text("q1_deg\n")

    def fill(v):
        if isinstance(v, str):
            return v.format(d=tmp_path)
        if isinstance(v, dict):
            return {fill(k): x for k, x in v.items()}
        return [fill(x) for x in v]

    with pytest.raises(InputError, match=match):
        check_output_paths(**{k: fill(v) for k, v in kwargs.items()})


def test_check_output_paths_accepts_good_paths(tmp_path):
    (tmp_path / "in.csv").write_text("q1_deg\n")
    check_output_paths(
        inputs=[tmp_path / "in.csv", None],
        outputs=[tmp_path / "new" / "o.csv", "-", None],
        folders=[tmp_path / "plots"],
    )


def test_outputs_written_only_at_commit(tmp_path):
    with Outputs() as out:
        out.add_text(tmp_path / "a.txt", "a")
        out.add_json(tmp_path / "b.json", {"b": 2})
        (out.folder(tmp_path / "plots") / "p.png").write_bytes(b"png")
        assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []
        written = out.commit()
    assert written == [tmp_path / "a.txt", tmp_path / "b.json", tmp_path / "plots" / "p.png"]
    assert (tmp_path / "a.txt").read_text() == "a"
    assert json.loads((tmp_path / "b.json").read_text()) == {"b": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.json", "plots"]


def test_failed_command_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), Outputs() as out:
        out.add_text(tmp_path / "a.txt", "a")
        (out.folder(tmp_path / "plots") / "p.png").write_bytes(b"png")
        raise RuntimeError("plotting failed")
    assert list(tmp_path.iterdir()) == []
