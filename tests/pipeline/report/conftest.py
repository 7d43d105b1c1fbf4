"""Fixtures of the report tests."""

import pytest

from pipeline import runner
from pipeline.core.session import Session
from tests.pipeline.tiny_session import lambert_stage, make_session


@pytest.fixture
def processed(tmp_path, monkeypatch):
    """The tiny session run up to integrate (the stub Lambertian normals stage)."""
    monkeypatch.setitem(runner.RUNNERS, "normals", lambert_stage)
    session = make_session(tmp_path)
    runner.run_session(session.root, stop="integrate")
    return Session.open(session.root)
