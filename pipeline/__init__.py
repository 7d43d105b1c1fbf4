"""psrig processing pipeline: session folders, image I/O, photometric stereo, integration.

The floor plan (docs/design.md):

- the ground floor, :mod:`.core`, used by :mod:`rig` and :mod:`calibration` too: the exception
  tree (``core.errors``), atomic writes, the session folder and its lock, the files stages hand
  each other (``core.paths``), image, light and raw files, transfer functions, yaml, progress,
  named parts (``core.registry``), compiled kernels (``core.jit``), the memory budget, the
  stage protocol (``core.stage``) and options as data (``core.options``); beside it
  :mod:`.settings`, every stage's and method's declared options;
- the stages' topics, each a subpackage with its own ``stage.py``: :mod:`.decode`,
  :mod:`.photometric`, :mod:`.integrate`, :mod:`.report`, and :mod:`.reflectance` (the BRDF
  models), :mod:`.importers` (data from elsewhere), :mod:`.evaluate` (errors against truth),
  :mod:`.relight` (the fitted model read back), :mod:`.experiments`;
- the top floor, which alone sees everything: :mod:`.cli`, :mod:`.runner`, :mod:`.cluster`,
  :mod:`.demo` (the root modules). No package imports one that imports it back
  (``tests/test_structure.py``).

Importing this package imports nothing else, so ``psrig --help`` stays fast.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
