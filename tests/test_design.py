"""docs/design.md is the contract: its options tables are the declarations' own."""

from pathlib import Path

import pytest

from pipeline import settings

DESIGN = Path(__file__).resolve().parents[1] / "docs" / "design.md"


@pytest.mark.parametrize("name", ["DecodeOptions", "CalibrateOptions", "NormalsOptions", "AlternationOptions",
                                  "IntegrateOptions", "ReportOptions"])
def test_the_design_states_each_stage_option_with_its_declared_default(name):
    table = getattr(settings, name).table()
    assert table in DESIGN.read_text(encoding="utf-8"), f"docs/design.md: the {name} table differs from the code (python docs/options_tables.py)"


def test_every_stage_is_described_with_the_file_it_lives_in():
    text = DESIGN.read_text(encoding="utf-8")
    from pipeline.runner import STAGE_OBJECTS

    for name, stage in STAGE_OBJECTS.items():
        module = type(stage).__module__.replace(".", "/") + ".py"
        assert module in text, (name, module)
