"""The paper's experiments (Sec. 3-5): each builds a table and a figure from a fixed seed.

Modules: :mod:`.cook_torrance` (Fig. 2 protocol and its sampling), :mod:`.merl` (Fig. 3),
:mod:`.models` (Fig. 4), :mod:`.reflectometry` (Fig. 5), :mod:`.ps` (Fig. 6, DiLiGenT) and
:mod:`.tables` (CSV / Markdown / PNG output).
"""

__all__ = []
