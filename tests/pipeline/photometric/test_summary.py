"""The one line psrig run / psrig normals print per session."""

from pipeline.photometric.summary import normals_summary


def test_summary_line_has_shares_and_the_lights_left_out():
    record = {"pixels": 200, "status_counts": {"ok": 150, "lambert_fallback": 50, "too_few": 0},
              "lights_left_out": [4, 7]}
    line = normals_summary(record)
    assert line.startswith("200 pixels: ok 75.0%, lambert_fallback 25.0%")
    assert "too_few" not in line
    assert line.endswith("lights left out (flagged in calibration/lights.yaml): 4, 7")
    assert "left out" not in normals_summary({**record, "lights_left_out": []})


def test_a_status_that_is_present_never_reads_as_absent():
    # 26 of 94365 pixels read "not_converged 0.0%" beside the px count that said otherwise
    line = normals_summary({"pixels": 94365, "status_counts": {"ok": 94289, "not_converged": 26,
                                                               "lambert_fallback": 50}})
    assert "not_converged <0.1%" in line and "lambert_fallback 0.1%" in line


def test_a_correction_says_how_well_the_highlights_fix_it():
    record = {"pixels": 100, "status_counts": {"ok": 100},
              "specular_anchor": {"anchor": "corrected", "cone_scale": 1.0545, "cone_scale_range": [1.05, 1.0832]}}
    line = normals_summary(record)
    assert "lights' cone scaled by 1.054 (specular anchor; 1.050-1.083 over resampled highlights)" in line
    del record["specular_anchor"]["cone_scale_range"]   # records written before the range was kept
    assert "lights' cone scaled by 1.054 (specular anchor)" in normals_summary(record)


def test_rescaled_frames_are_named_and_a_decode_curve_is_suspected_too():
    from pipeline.photometric.summary import normals_warnings

    one = {"verdict": "rescaled", "rescaled": {"object_004": 0.61}, "uncalibrated": False}
    warnings = normals_warnings({"ok": 100}, 12, {}, one, ["linear (assumed: 16-bit file without colour metadata)"])
    assert len(warnings) == 1 and warnings[0].startswith("frame(s) object_004 (0.61x): ")
    assert "--gamma" not in warnings[0]
    warnings = normals_warnings({"ok": 100}, 12, {}, one, ["sRGB (assumed: 8-bit file without colour metadata)"])
    assert "decode used sRGB (assumed: 8-bit file without colour metadata)" in warnings[0]
    assert "--gamma linear" in warnings[0]
    many = {"verdict": "rescaled", "rescaled": {f"f{k}": 0.5 + k / 10 for k in range(8)}, "uncalibrated": True}
    (text,) = normals_warnings({"ok": 100}, 12, {}, many)
    assert text.startswith("8 of 12 frames are not as bright") and "0.50x to 1.20x" in text
    assert "were the intensities given" in text and "directions were not judged" in text
    off = {"off": {"f1": {"angle": 8.0, "estimated": [0.1, 0.2, 0.97]}}, "swapped": [], "dark": []}
    assert len(normals_warnings({"ok": 100}, 12, {}, dict(many, directions=off))) == 1
    assert len(normals_warnings({"ok": 100}, 12, {}, dict(one, directions=off))) == 2
    assert normals_warnings({"ok": 100}, 12, {}, {"verdict": "consistent", "max_deviation": 0.02}) == []
    line = normals_summary({"pixels": 100, "status_counts": {"ok": 100}, "frame_gains": one})
    assert line.endswith("; 1 frame(s) rescaled to the others' brightness")


def test_a_healthy_status_share_over_a_doubtful_result_leads_with_the_doubt():
    many = {"verdict": "rescaled", "rescaled": {f"f{k}": 0.5 + k / 10 for k in range(8)}, "uncalibrated": True}
    line = normals_summary({"pixels": 100, "status_counts": {"ok": 96, "too_few": 4}, "frame_gains": many})
    assert line.startswith("100 pixels, normals doubtful (the frames' brightness does not follow the lights' "
                           "intensities: the whole map may be tilted; see the warning); fit status: ok 96.0%")
    fine = normals_summary({"pixels": 100, "status_counts": {"ok": 100}})
    assert fine.startswith("100 pixels: ok 100")
