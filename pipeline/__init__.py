"""psrig processing pipeline: session folders, image I/O, photometric stereo, integration.

The floor plan (docs/design.md):

- ground floor, used by :mod:`rig` and :mod:`calibration` too: :mod:`.errors` (the exception
  tree), :mod:`.atomic` (atomic writes), :mod:`.session` (the session folder and its
  manifest), :mod:`.paths` (the files stages hand each other), :mod:`.imageio`,
  :mod:`.lightsio` and :mod:`.dng` (image, light and raw files), :mod:`.gamma` (transfer
  functions), :mod:`.yamlio`, :mod:`.progress`, :mod:`.registry` (named parts),
  :mod:`.jit` (compile or fall back), :mod:`.golden` (a 1-D search), and :mod:`.core` (the
  stage protocol and options as data) with :mod:`.settings` (every stage's declared options);
- the stages' topics, each a subpackage with its own ``stage.py``: :mod:`.decode`,
  :mod:`.photometric`, :mod:`.integrate`, :mod:`.report`, and :mod:`.reflectance` (the BRDF
  models), :mod:`.importers` (data from elsewhere), :mod:`.evaluate` (errors against truth);
- the top floor, which alone sees everything: :mod:`.cli`, :mod:`.runner`, :mod:`.cluster`,
  :mod:`.demo`, :mod:`.experiments`.

Importing this package imports nothing else, so ``psrig --help`` stays fast.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
