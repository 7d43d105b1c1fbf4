"""The capture's stop message tells the truth about the lights: when a light controller refuses
``ON`` and then every ``OFF`` (the simulated firmware answering ``ERR``), the operator is told
which light may still be on and to check the rig, never "the lights are switched off"."""

import pytest

from pipeline.cli import main
from rig.capture import CaptureError, capture_session
from rig.config import get_rig
from rig.sim.rig import SimulatedRig
from tests.rig.test_capture import QUIET, RIGS


@pytest.fixture
def rigs_path(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return path


def test_cli_says_which_light_may_be_on_when_off_is_refused(tmp_path, rigs_path, monkeypatch, capsys):
    root = tmp_path / "s"
    monkeypatch.setenv("PSRIG_SIM_FAULTS", "err:50@object_005")   # ON 5, then every OFF: ERR
    assert main(["capture", str(root), "--rig", "sim8", "--config", str(rigs_path)]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "switched off" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "frame object_005 (light 5)" in err
    assert "light 4 may still be on" in err, err
    assert "check the rig" in err, err


def test_the_lights_are_said_off_only_when_off_was_acknowledged(tmp_path, rigs_path):
    rig = get_rig("sim8", rigs_path)
    with SimulatedRig(rig, faults={("interlock", "object_003"): 1}) as sim:
        with pytest.raises(CaptureError) as info:
            capture_session(tmp_path / "a", rig, sim=sim, **QUIET)
        assert sim.firmware.lit is None
    assert "Stopped: the lights are switched off" in str(info.value)
    with SimulatedRig(rig, faults={("err", "object_003"): 50}) as sim:
        with pytest.raises(CaptureError) as info:
            capture_session(tmp_path / "b", rig, sim=sim, **QUIET)
        lit = sim.firmware.lit
    assert lit == 2
    assert "switched off" not in str(info.value)
    assert "light 2 may still be on" in str(info.value)


def test_ctrl_c_with_the_off_refused_says_which_light_may_be_on(tmp_path, rigs_path, monkeypatch, capsys):
    """Ctrl-C while light 4 is lit, the controller then answering ERR to every command: the
    interrupt line says light 4 may still be on, not "lights switched off"."""
    import rig.sim.rig as sim_rig

    class Interrupting(sim_rig.SimulatedRig):
        def open(self):
            super().open()
            render = self.backend.camera.render

            def sensor():
                if self.scene == "object" and self.firmware.lit == 4:
                    self.firmware.inject("err", 50)
                    raise KeyboardInterrupt
                return render()
            self.backend.camera.render = sensor
            return self

    monkeypatch.setattr(sim_rig, "SimulatedRig", Interrupting)
    monkeypatch.setenv("PSRIG_SIM_FAULTS", "garble:0")   # the CLI makes its SimulatedRig only with faults
    assert main(["capture", str(tmp_path / "s"), "--rig", "sim8", "--config", str(rigs_path)]) == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err and "switched off" not in err, err
    assert "light 4 may still be on" in err and "check the rig" in err, err
