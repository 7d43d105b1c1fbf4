"""The normals stage within a memory budget: tiles from a memory-mapped stack when the stack does
not fit (the same normals as in memory), a clear refusal when nothing fits."""

import numpy as np
import pytest

from pipeline.core import memory
from pipeline.core.errors import InputError, StageError
from pipeline.core.paths import NORMALS
from pipeline.photometric import normals_session
from pipeline.photometric import tiles
from pipeline.photometric.stage import normals_memory, read_workers, stack_shape, _object_frames
from tests.pipeline.photometric.test_stack_read import rgb_session  # noqa: F401 (fixture)

FILES = ("normals/normals.exr", "normals/albedo.exr", "normals/residual.exr", "normals/brdf.exr", "normals/status.png")


def estimates(session):
    return normals_memory(stack_shape(session, _object_frames(session)), read_workers())


def outputs(session):
    return {name: session.path(name).read_bytes() for name in FILES}


def test_tiled_normals_are_identical_to_the_in_memory_solve(rgb_session, monkeypatch):  # noqa: F811
    monkeypatch.setattr(tiles, "SERIAL_TILE_PIXELS", 512)   # several tiles on a small object
    whole = normals_session(rgb_session, force=True, show_progress=False)
    assert whole["memory"]["execution"] == "in memory"
    expected = outputs(rgb_session)
    needs = estimates(rgb_session)
    tiled = normals_session(rgb_session, force=True, show_progress=False, memory=needs["in_memory"] - 1)
    assert tiled["memory"]["execution"] == "tiled"
    assert tiled["memory"]["budget_gb"] == round((needs["in_memory"] - 1) / 2 ** 30, 2)
    assert outputs(rgb_session) == expected
    assert tiled["status_counts"] == whole["status_counts"] and tiled["params"] == whole["params"]
    assert not rgb_session.path(tiles.SCRATCH).exists()


def test_a_budget_nothing_fits_is_refused_before_reading(rgb_session):  # noqa: F811
    before = rgb_session.path(NORMALS).exists()
    with pytest.raises(StageError, match=r"normals: needs about [\d.]+ GB of memory, the budget is 0.00 GB "
                                         r"\([\d.]+ GB available\); give more with --memory"):
        normals_session(rgb_session, force=True, show_progress=False, memory="1M")
    assert rgb_session.path(NORMALS).exists() == before


@pytest.mark.parametrize("text, expected", [("8G", 8 * 2 ** 30), ("1500M", 1500 * 2 ** 20), ("2GB", 2 * 2 ** 30),
                                            (12345, 12345), ("0.5G", 2 ** 29)])
def test_budget_sizes(text, expected):
    assert memory.budget_bytes(text) == expected


def test_budget_shares_and_default_follow_the_available_memory(monkeypatch):
    monkeypatch.setattr(memory, "available_bytes", lambda: 10 * 2 ** 30)
    assert memory.budget_bytes("50%") == 5 * 2 ** 30
    assert memory.budget_bytes(None) == int(memory.DEFAULT_SHARE * 10 * 2 ** 30)


@pytest.mark.parametrize("text", ["lots", "-1G", "0", "8 X"])
def test_unreadable_budgets_are_refused(text):
    with pytest.raises(InputError, match="--memory"):
        memory.budget_bytes(text)


def test_integrate_refuses_a_session_over_its_budget_and_records_the_budget(rgb_session):  # noqa: F811
    from pipeline.integrate import integrate_session
    from pipeline.integrate.stage import integrate_memory
    from pipeline.core.imageio import read_mask

    normals_session(rgb_session, method="lambert", show_progress=False)
    with pytest.raises(StageError, match=r"integrate: needs about [\d.]+ GB of memory, the budget is 0.00 GB .*"
                                         r"--memory"):
        integrate_session(rgb_session, memory="1M")
    assert rgb_session.stage("integrate") is None
    integrate_session(rgb_session, memory="4G")
    needs = integrate_memory(read_mask(rgb_session.path("normals/mask.png")))
    assert rgb_session.stage("integrate")["memory"] == {"budget_gb": 4.0, "estimate_gb": round(needs / 2 ** 30, 2)}
