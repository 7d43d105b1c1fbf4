"""Options are data: one declaration gives the flags, the validation, the record and its replay."""

import numpy as np
import pytest

from pipeline import runner
from pipeline.cli import main
from pipeline.core.errors import InputError
from pipeline.photometric import estimate_normals
from pipeline.photometric.methods import METHODS, check_method_options, method_traits
from pipeline.core.session import Session
from pipeline.settings import BiquadraticOptions, NormalsOptions, SelectionOptions
from tests.pipeline.tiny_session import make_session


def test_a_misspelt_option_of_the_api_is_an_error_listing_the_known_ones():
    lights = np.array([[0, 0, 1], [0.5, 0, 0.87], [0, 0.5, 0.87], [-0.5, 0, 0.87]])
    images = np.ones((4, 6, 6), np.float32)
    with pytest.raises(InputError, match=r"unknown option 'reject_K' for the biquadratic method; known: .*reject_k"):
        estimate_normals(images, lights, reject_K=3)
    with pytest.raises(InputError, match="unknown option 'shape_prior' for the lambert method"):
        estimate_normals(images, lights, method="lambert", shape_prior=0.1)
    with pytest.raises(InputError, match="t_low must be in"):
        estimate_normals(images, lights, t_low=1.5)


def test_a_misspelt_flag_names_the_flags_the_command_takes(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["normals", str(tmp_path), "--reject-K", "3"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "usage: psrig normals" in err
    assert "unrecognized arguments: --reject-K 3" in err and "psrig normals takes: " in err and "--reject-k" in err
    with pytest.raises(SystemExit):
        main(["run", str(tmp_path), "--t-shadw", "0.1"])
    assert "unrecognized arguments: --t-shadw" in capsys.readouterr().err


def test_run_takes_every_normals_option_and_the_stage_records_it(tmp_path):
    session = make_session(tmp_path)
    assert main(["run", str(session.root), "--method", "lambert-low", "--t-shadow", "0.1", "--reject-k", "3",
                 "--to", "normals", "-q"]) == 0
    params = Session.open(session.root).stage("normals")["params"]
    assert params == {"method": "lambert-low", "reject_k": 3.0, "t_shadow": 0.1}
    # a later run keeps them; a changed one reruns the stage with the others kept
    outcomes = runner.run_session(session.root, stop="normals")
    assert not outcomes[-1].ran
    runner.run_session(session.root, options={"normals": {"t_shadow": 0.2}}, stop="normals")
    assert Session.open(session.root).stage("normals")["params"] == {"method": "lambert-low", "reject_k": 3.0,
                                                                     "t_shadow": 0.2}


def test_a_new_method_drops_the_recorded_options_it_does_not_take():
    recorded = {"method": "biquadratic", "shape_prior": 0.1, "t_shadow": 0.1, "align": "off"}
    merged = runner.STAGE_OBJECTS["normals"].merge(recorded, {"method": "lambert"})
    assert merged == {"method": "lambert", "t_shadow": 0.1, "align": "off"}


def test_declarations_give_the_flags_help_with_defaults_and_parse_percentages():
    from pipeline.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["normals", "S", "--t-low", "30", "--specular-anchor", "off", "--near-depth", "off"])
    assert NormalsOptions.from_args(args) == {"t_low": 0.3, "specular_anchor": False, "near_depth": False}
    assert "(default: 2.5)" in NormalsOptions.help_line("reject_k")
    assert NormalsOptions.of({"t_low": 0.3, "near_depth": False}).record() == \
        {"method": "biquadratic", "near_depth": False, "t_low": 0.3}


def test_methods_say_what_they_are_by_their_traits_not_their_names():
    assert METHODS.group == "psrig.methods"
    biquadratic, lambert = method_traits(METHODS["biquadratic"]), method_traits(METHODS["lambert"])
    assert biquadratic.options is BiquadraticOptions and biquadratic.renders_rho and biquadratic.wants_anchor
    assert lambert.options is SelectionOptions and not lambert.renders_rho and not lambert.wants_anchor
    assert method_traits(METHODS["bicubic"]).options.defaults()["max_iter"] == 20
    assert check_method_options("lambert-low", {"t_low": 0.3, "frame_gains": False}) == \
        {"t_low": 0.3, "frame_gains": False}
