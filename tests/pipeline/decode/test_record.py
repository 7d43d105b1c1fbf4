"""How a decode record's failures are told: one line per distinct reason, its frames named."""

from pipeline.decode import describe_failures


def test_frames_failing_alike_are_one_line():
    crash = "decoder crashed: BrokenProcessPool: A process in the process pool was terminated abruptly"
    failed = {f"object_{i:03d}": crash for i in range(66)}
    failed["dark_000"] = "raw/dark_000.dng: 1 value NaN or infinite; a frame must hold finite linear values"
    failed["object_099"] = "cannot read it"
    lines = describe_failures(failed)
    assert lines == [f"object_000, object_001, object_002 and 63 more: {crash}",
                     failed["dark_000"],            # its reason names it already
                     "object_099: cannot read it"]
    assert describe_failures({}) == [] and describe_failures(None) == []
