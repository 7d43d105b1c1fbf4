"""psrig's tests, one folder per package (tests/pipeline/photometric mirrors pipeline/photometric).

Real data made by others lies in ``../shared/data`` beside the repository (docs/design.md); tests
that need it skip when it is absent.
"""

from pathlib import Path

#: ../shared/data beside the repository
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
