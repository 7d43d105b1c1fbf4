"""A manifest that was cut short, edited into wrong types or given aliases is refused with one
clear line naming the key, by the command line as much as by the library."""

import time

import pytest
import yaml

from pipeline.cli import main
from pipeline.core.errors import ManifestError
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


@pytest.fixture
def root(tmp_path):
    session = make_session(tmp_path)
    assert main(["run", str(session.root), "--to", "decode"]) == 0
    return session.root


def edit(root, change):
    path = root / "session.yaml"
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def refused(root, capsys, command="report", match=None):
    """Run a command on the session; it must fail with one line (naming ``match``)."""
    code = main([command, str(root)])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    if match:
        assert match in err, err
    return err


@pytest.mark.parametrize("where, value, key", [
    (("frames", 0, "applies_to"), 5, "frames[0].applies_to"),
    (("frames", 0, "source"), ["a"], "frames[0].source"),
    (("stages", "decode", "frames"), 5, "stages.decode.frames"),
    (("stages", "decode", "seconds"), "abc", "stages.decode.seconds"),
    (("stages", "decode", "seconds"), float("nan"), "stages.decode.seconds"),
    (("stages", "decode", "status"), "done", "stages.decode.status"),
    (("stages", "decode", "failed"), ["x"], "stages.decode.failed"),
    (("stages", "decode", "subtracted"), {"kind": 3}, "stages.decode.subtracted.kind"),
    (("stages", "decode", "frames", "object_000"), 7, "stages.decode.frames.object_000"),
    (("lights", "object_mask"), "../elsewhere.png", "lights.object_mask"),
    (("saved",), None, "'saved'"),
    (("saved",), 5, "'saved'"),
])
def test_wrong_types_in_stored_fields_are_named(root, capsys, where, value, key):
    def change(data):
        node = data
        for part in where[:-1]:
            node = node[part]
        node[where[-1]] = value
    edit(root, change)
    refused(root, capsys, match=key)


def test_a_manifest_cut_at_a_frame_boundary_is_refused(root, capsys):
    path = root / "session.yaml"
    text = path.read_text()
    # the last frame and everything after it gone, at a line boundary
    cut = text[:text.index("- id: object_007")]
    path.write_text(cut)
    refused(root, capsys, match="cut short")
    path.write_text(text)
    lines = text.splitlines(keepends=True)
    frames = lines.index("frames:\n")
    ends = [i for i, line in enumerate(lines) if line.startswith("- id: ") and i > frames]
    # a whole frame entry removed from the middle: the count no longer matches
    path.write_text("".join(lines[:ends[2]] + lines[ends[3]:]))
    err = refused(root, capsys, match="lists 7 frames but was saved with 8")
    assert "frame_count: 7" in err


def test_older_manifests_without_a_count_still_open(root):
    edit(root, lambda data: [data.pop("frame_count"), data.pop("saved")])
    session = Session.open(root, writer="run")
    session.save()
    assert Session.open(root).manifest["frame_count"] == len(session.frames())


def test_an_older_manifest_that_lost_frames_is_not_written_over(root, capsys):
    """Without frame_count a cut cannot show in the manifest; raw files no frame names do."""
    edit(root, lambda data: [data.pop("frame_count"), data.pop("saved"), data.update(frames=data["frames"][:5])])
    before = (root / "session.yaml").read_text()
    err = refused(root, capsys, command="run", match="raw/ holds 3 file(s) no frame names")
    assert "--resume" in err
    assert (root / "session.yaml").read_text() == before, "nothing written"
    Session.open(root, writer="capture").release()   # capture --resume may open it to adopt them


def test_duplicate_file_entries_are_refused_when_read(root, capsys):
    def change(data):
        data["frames"][2]["file"] = data["frames"][3]["file"]
        data["frames"][2]["sha256"] = data["frames"][3]["sha256"]
    edit(root, change)
    err = refused(root, capsys, command="decode", match="both name 'raw/object_003.png'")
    assert "object_002" in err and "object_003" in err
    with pytest.raises(ManifestError, match="every frame has a raw file of its own"):
        Session.open(root)


def test_yaml_aliases_in_a_manifest_are_refused_at_once(root, capsys):
    path = root / "session.yaml"
    # 7 levels of 9-fold aliases in the rig description (which the report shows): a few hundred
    # bytes that expand to 9**7 strings
    bomb = ["l0: &l0 [" + ", ".join(["xxxxxxxx"] * 9) + "]"]
    bomb += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, 7)]
    path.write_text(path.read_text().replace("rig:\n", "rig:\n" + "".join(f"  {b}\n" for b in bomb)))
    start = time.perf_counter()
    err = refused(root, capsys, match="alias")
    assert time.perf_counter() - start < 10
    assert "session.yaml" in err and "line" in err
