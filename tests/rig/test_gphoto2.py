"""The gphoto2 camera driver: against libgphoto2's own virtual PTP camera (vusb, shipped in
python-gphoto2's wheels; needs VCAMERADIR set before gphoto2 is imported, so it runs in a
subprocess), and against a small fake of the module for the error mapping."""

import os
import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest

from rig.camera import CameraBusy, CameraDisconnected, CameraExposureError, CameraNotFound, CameraTimeout
from rig.gphoto2_camera import Gphoto2Camera

HAVE_GPHOTO2 = subprocess.run([sys.executable, "-c", "import gphoto2"], capture_output=True).returncode == 0


@pytest.mark.skipif(not HAVE_GPHOTO2, reason="python-gphoto2 is not installed (pip install 'psrig[gphoto2]')")
def test_capture_with_the_virtual_camera_of_libgphoto2(tmp_path):
    import cv2

    images = tmp_path / "vcam"
    images.mkdir()
    cv2.imwrite(str(images / "a.jpg"), (np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8))
    rigs = tmp_path / "rigs.yaml"
    rigs.write_text(textwrap.dedent("""
        rigs:
          vcam:
            lights: {driver: sim, count: 2, timeout: 0.4, rings: [{elevation: 50, count: 2}]}
            camera: {driver: gphoto2}
            exposure: {shutter: 1/50, aperture: 5.6}
            frames: {dark: 1, ambient: 0, sphere: false}
            raw_format: dng
          wrong:
            lights: {driver: sim, count: 2, timeout: 0.4, rings: [{elevation: 50, count: 2}]}
            camera: {driver: gphoto2}
            exposure: {shutter: 1/30}
          noiso:
            lights: {driver: sim, count: 2, timeout: 0.4, rings: [{elevation: 50, count: 2}]}
            camera: {driver: gphoto2}
            exposure: {iso: 100}
    """))
    env = {**os.environ, "VCAMERADIR": str(images)}
    def psrig(*args):
        return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], env=env, capture_output=True,
                              text=True, timeout=120)
    done = psrig("capture", str(tmp_path / "s"), "--rig", "vcam", "--config", str(rigs), "--no-preview-check")
    assert done.returncode == 0, done.stderr
    import yaml
    manifest = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    assert [f["file"] for f in manifest["frames"]] == ["raw/dark_000.jpg", "raw/object_000.jpg", "raw/object_001.jpg"]
    assert manifest["frames"][1]["camera_file"].startswith("GPH_")
    assert manifest["camera"]["exposure"]["shutter"]["device_value"] == "0.0200s"
    assert manifest["camera"]["exposure"]["aperture"]["device_value"] == "f/5.6"
    wrong = psrig("capture", str(tmp_path / "w"), "--rig", "wrong", "--config", str(rigs), "--no-preview-check")
    assert wrong.returncode == 1 and "Traceback" not in wrong.stderr
    assert "exposure.shutter: '1/30': 1/30 s is not offered by the camera; nearest allowed: 1/50 s, 1/20 s" in wrong.stderr
    noiso = psrig("capture", str(tmp_path / "n"), "--rig", "noiso", "--config", str(rigs), "--no-preview-check")
    assert noiso.returncode == 1 and "offers no iso / isospeed setting" in noiso.stderr


class FakeError(Exception):
    def __init__(self, code):
        super().__init__(f"[{code}] fake")
        self.code = code


def fake_module(fail_capture=None):
    """A stand-in for python-gphoto2 with one camera whose capture fails with a code."""
    class FakeCamera:
        def init(self):
            pass

        def get_summary(self):
            return "Manufacturer: Fake\nModel: F1\n  Serial Number: 7\n"

        def capture(self, kind):
            raise FakeError(fail_capture)

        def exit(self):
            pass

    return types.SimpleNamespace(GPhoto2Error=FakeError, Camera=FakeCamera, GP_CAPTURE_IMAGE=0,
                                 GP_FILE_TYPE_NORMAL=1)


@pytest.mark.parametrize("code, error", [(-110, CameraBusy), (-10, CameraTimeout), (-7, CameraDisconnected),
                                         (-52, CameraNotFound), (-105, CameraNotFound)])
def test_gphoto2_errors_become_camera_errors(code, error):
    with Gphoto2Camera(gp=fake_module(fail_capture=code)) as camera:
        assert camera.device_info["model"] == "F1" and camera.device_info["serial"] == "7"
        with pytest.raises(error, match=rf"camera F1: capturing \(gp_camera_capture\): gphoto2 error {code}"):
            camera.capture()


def test_exposure_key_that_is_not_a_number_is_refused():
    with Gphoto2Camera(gp=fake_module()) as camera:
        with pytest.raises(CameraExposureError, match="not a number"):
            camera.set_exposure({"shutter": "soon"})
