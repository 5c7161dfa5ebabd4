"""recordings.json: a change appends one line (what was written before is never touched),
a torn last write loses only that change, a removed recording leaves the file, and the
file stays one JSON list (a backup reads it as such)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from app.server import recording_file as rf
from app.server.recording import Part, Recording, RecordingManager
from app.server.registry import NodeRegistry


def _rec(k: int, state: str = "on_node") -> Recording:
    rid = f"R20260101-1000{k:02d}-ab{k:02d}"
    return Recording(rid, 1767261600.0 + k, 1767261625.0 + k, 1767261599.0 + k, ["depth"], 1,
                     {"S1": Part("S1", state, None, 750, 4096, 1.0, 26.0, 1767261600.0,
                                 1767261625.0, {"offset_s": 0.5, "drift": 0.0, "t_ref": 3.0}),
                      "S2": Part("S2", "complete", "kept", 10, 9, on_server=True)})


def _manager(data: Path, n: int = 0) -> RecordingManager:
    rm = RecordingManager(NodeRegistry(), data)
    for k in range(n):
        rm.recordings[_rec(k).id] = _rec(k)
    rm.save()
    return rm


def _reload(data: Path) -> dict[str, Recording]:
    return dict(RecordingManager(NodeRegistry(), data).recordings)


def test_a_change_appends_one_line_and_leaves_the_rest_untouched(tmp_path: Path) -> None:
    rm = _manager(tmp_path, 50)
    before = rm.path.read_bytes()
    rec = rm.recordings[_rec(7).id]
    rec.parts["S1"].state, rec.parts["S1"].reason = "incomplete", "node S1 disconnected"
    rm.touch(rec.id)
    rm.save()
    after = rm.path.read_bytes()
    # everything but the closing bracket is kept byte for byte; one line more
    assert after[:len(before) - len(rf.CLOSE)] == before[:-len(rf.CLOSE)]
    assert after.count(b"\n") == before.count(b"\n") + 1
    assert rm.save_error is None
    raw = json.loads(after)  # still one JSON list (a backup reads it so)
    assert [r["id"] for r in raw[1:]].count(rec.id) == 2
    again = _reload(tmp_path)
    assert len(again) == 50
    assert asdict(again[rec.id]) == asdict(rec)
    assert asdict(again[_rec(8).id]) == asdict(_rec(8))
    rm.save()  # nothing changed since: nothing written
    assert rm.path.read_bytes() == after


@pytest.mark.parametrize("cut", ["mid_line", "no_closing", "half_bracket"])
def test_a_torn_last_write_loses_only_that_change(tmp_path: Path, cut: str) -> None:
    rm = _manager(tmp_path, 20)
    rec = rm.recordings[_rec(3).id]
    rec.parts["S1"].state = "incomplete"
    rm.touch(rec.id)
    rm.save()
    good = rm.path.read_bytes()  # the state before the write a crash tears
    rec.parts["S1"].reason = "torn away"
    rm.touch(rec.id)
    rm.save()
    full = rm.path.read_bytes()
    line = full[len(good) - len(rf.CLOSE):-len(rf.CLOSE)]  # the appended ",{...}\n"
    torn = {"mid_line": full[:len(good) - len(rf.CLOSE) + len(line) // 2],
            "no_closing": full[:-len(rf.CLOSE)],  # the line whole, the "]" never written
            "half_bracket": full[:-1]}[cut]
    rm.path.write_bytes(torn)
    again = _reload(tmp_path)
    assert len(again) == 20  # every earlier recording and state
    want = "torn away" if cut != "mid_line" else None  # a whole line counts
    assert again[rec.id].parts["S1"].state == "incomplete"
    assert again[rec.id].parts["S1"].reason == want
    assert asdict(again[_rec(19).id]) == asdict(_rec(19))
    fixed = json.loads(rm.path.read_bytes())  # rewritten, whole again
    assert len(fixed) == 21 and rm.path.read_bytes().startswith(rf.HEADER)
    # and it is appended to again as before
    rm2 = RecordingManager(NodeRegistry(), tmp_path)
    rm2.recordings[_rec(30).id] = _rec(30)
    rm2.save()
    assert set(_reload(tmp_path)) == set(again) | {_rec(30).id}


def test_a_torn_first_line_keeps_nothing_and_breaks_nothing(tmp_path: Path) -> None:
    rm = _manager(tmp_path, 1)
    rm.path.write_bytes(rf.HEADER + b',{"id": "R2026')
    assert _reload(tmp_path) == {}
    assert json.loads(rm.path.read_bytes()) == json.loads(rf.HEADER + rf.CLOSE)


def test_a_file_of_an_older_server_is_read_and_rewritten(tmp_path: Path) -> None:
    recs = [_rec(k) for k in range(3)]
    (tmp_path / "recordings.json").write_text(json.dumps([asdict(r) for r in recs]))
    again = _reload(tmp_path)
    assert [asdict(again[r.id]) for r in recs] == [asdict(r) for r in recs]
    assert (tmp_path / "recordings.json").read_bytes().startswith(rf.HEADER)
    assert _reload(tmp_path).keys() == again.keys()


def test_a_removed_recording_leaves_the_file(tmp_path: Path) -> None:
    rm = _manager(tmp_path, 5)
    gone = _rec(2).id
    rm.recordings[gone].parts["S1"].state = "incomplete"
    rm.touch(gone)
    rm.save()  # two lines of it now
    rm.recordings.pop(gone)
    rm.save()
    assert gone not in rm.path.read_text()
    assert set(_reload(tmp_path)) == {_rec(k).id for k in (0, 1, 3, 4)}


def test_the_file_stays_bounded_by_twice_the_recordings(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rf, "SLACK_LINES", 10)
    rm = _manager(tmp_path, 10)
    rec = rm.recordings[_rec(0).id]
    for i in range(100):
        rec.parts["S1"].n_frames = i
        rm.touch(rec.id)
        rm.save()
        lines = rm.path.read_bytes().count(b"\n")
        assert lines <= 2 + 2 * 10 + 10
    assert _reload(tmp_path)[rec.id].parts["S1"].n_frames == 99


def test_a_recording_changed_without_a_note_is_not_written(tmp_path: Path) -> None:
    """What a save writes is what was noted (touch, or the manager's own changes): the
    cost of a save does not depend on the recordings kept."""
    rm = _manager(tmp_path, 3)
    rm.recordings[_rec(1).id].parts["S1"].n_frames = 5
    rm.save()
    assert _reload(tmp_path)[_rec(1).id].parts["S1"].n_frames == 750
    rm.touch(_rec(1).id)
    rm.save()
    assert _reload(tmp_path)[_rec(1).id].parts["S1"].n_frames == 5


def test_an_unreadable_recording_is_left_out_not_the_file(tmp_path: Path) -> None:
    good = json.dumps(asdict(_rec(1)), separators=(",", ":")).encode()
    bad = json.dumps({"id": "R1", "t_start": 1.0, "parts": {"S1": {"nope": 1}}}).encode()
    (tmp_path / "recordings.json").write_bytes(rf.HEADER + b"," + bad + b"\n," + good
                                               + b"\n" + rf.CLOSE)
    assert list(_reload(tmp_path)) == [_rec(1).id]


def test_a_file_removed_under_the_server_is_written_again(tmp_path: Path) -> None:
    rm = _manager(tmp_path, 3)
    rm.path.unlink()
    rec = rm.recordings[_rec(1).id]
    rec.parts["S1"].n_frames = 9
    rm.touch(rec.id)
    rm.save()  # the append fails: said, kept for the next save
    assert rm.save_error is not None
    rm.touch(rec.id)
    rm.save()
    assert rm.save_error is None
    again = _reload(tmp_path)
    assert len(again) == 3 and again[rec.id].parts["S1"].n_frames == 9
