"""Integrate's count of pixels dropped for want of a normal names the normals stage's reasons,
so that it adds up with the normals line (which warns only of statuses above their limits)."""

import numpy as np

from pipeline.cli import main
from pipeline.core.imageio import read_image, write_image
from pipeline.integrate import integrate_session
from pipeline.core.session import Session

from tests.pipeline.tiny_session import lambert_stage, make_session


def test_dropped_pixels_are_explained_by_the_normals_statuses(tmp_path):
    session = make_session(tmp_path)
    assert main(["run", str(session.root), "--to", "decode", "-q"]) == 0
    lambert_stage(session, {}, False, 1)
    normals = read_image(session.path("normals/normals.exr"))
    normals[18:20, 18:21] = np.nan    # 6 pixels without a normal, as the stage records below
    write_image(session.path("normals/normals.exr"), normals.astype(np.float32))
    manifest = Session.open(session.root)
    record = manifest.stage("normals")
    record["status_counts"] = {**record.get("status_counts", {}), "shadowed": 2, "ill_posed": 4}
    manifest.manifest["stages"]["normals"] = record
    manifest.save()
    result = integrate_session(Session.open(session.root))
    dropped = [w for w in result.warnings if "non-finite or zero normals" in w]
    assert dropped and dropped[0].startswith("dropped from the mask: 6 masked pixel(s)")
    assert "(the normals stage gave them none: shadowed 2, ill_posed 4, by its status counts)" in dropped[0]
