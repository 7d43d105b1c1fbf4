"""Rig files: anchors that share a part are fine; aliases that explode are one error line."""

from pipeline.cli import main
from rig.config import load_rigs

def test_shared_parts_of_a_rig_file_are_read(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text("rigs:\n  a: &a\n    lights: {driver: sim, count: 8, rings: [{elevation: 45, count: 8}]}\n"
                    "    camera: {driver: sim}\n  b: *a\n")
    rigs = load_rigs(path)
    assert rigs["a"].lights.count == rigs["b"].lights.count == 8


def test_an_alias_bomb_in_a_rig_file_is_one_error_line(tmp_path, capsys):
    lines = ["x0: &x0 [" + ", ".join(["yyyyyyyy"] * 9) + "]"]
    lines += [f"x{i}: &x{i} [" + ", ".join([f"*x{i - 1}"] * 9) + "]" for i in range(1, 8)]
    path = tmp_path / "rigs.yaml"
    path.write_text("\n".join(lines) + "\nrigs: {}\n")
    assert main(["rigs", "--config", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: not valid YAML: line" in err and "aliases" in err, err
