"""`psrig --help` and a mistyped command answer at once: building the parser imports nothing heavy."""

import subprocess
import sys

HEAVY = ("numpy", "scipy", "matplotlib", "OpenImageIO", "cv2", "numba", "dask", "rawpy", "pyamg", "tqdm")


def test_building_the_parser_imports_no_heavy_module():
    code = ("import sys; from pipeline.cli import build_parser; build_parser(); "
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == ""


def test_help_and_a_typo_answer_without_a_traceback():
    helped = subprocess.run([sys.executable, "-m", "pipeline.cli", "--help"], capture_output=True, text=True)
    assert helped.returncode == 0 and "report" in helped.stdout
    typo = subprocess.run([sys.executable, "-m", "pipeline.cli", "rnu"], capture_output=True, text=True)
    assert typo.returncode == 2 and "invalid choice" in typo.stderr and "Traceback" not in typo.stderr


def test_the_run_command_spells_the_stages_as_the_session_does():
    from pipeline.cli.run import STAGES
    from pipeline.core.session import STAGES as SESSION_STAGES

    assert STAGES == SESSION_STAGES


def test_the_decode_command_spells_the_compressions_as_decoding_does():
    from pipeline.cli.decode import COMPRESSIONS
    from pipeline.decode import COMPRESSIONS as DECODE_COMPRESSIONS

    assert COMPRESSIONS == DECODE_COMPRESSIONS
