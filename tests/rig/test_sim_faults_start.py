"""Faults of the simulated camera armed from the start of a capture (before the session with
the camera is open) are struck like any other, never a crash of the simulator."""

from pipeline.cli import main
from tests.rig.test_capture import RIGS


def test_a_stale_response_armed_from_the_start(tmp_path, monkeypatch, capsys):
    """The first command (transaction 0) is preceded by a response of "transaction -1", which
    the simulator packed as a negative number (struct.error); it is the transaction before 0
    modulo 2**32, and the driver refuses it by name in one line."""
    rigs = tmp_path / "rigs.yaml"
    rigs.write_text(RIGS, encoding="utf-8")
    command = ["capture", str(tmp_path / "s"), "--rig", "sim8", "--config", str(rigs)]
    monkeypatch.setenv("PSRIG_SIM_FAULTS", "stale_response")
    assert main(command) == 1
    err = capsys.readouterr().err
    assert "struct.error" not in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert "transaction 4294967295 arrived while waiting for transaction 0" in err, err
    monkeypatch.delenv("PSRIG_SIM_FAULTS")
    assert main(command) == 0
