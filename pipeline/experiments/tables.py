"""Experiment output: a table as CSV and Markdown, a figure as PNG, all written atomically."""

import csv
import io
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["Table", "write_outputs", "save_figure", "format_value"]


class Table:
    """A titled table: ``columns`` (header strings) and ``rows`` (lists, first cell a label)."""

    def __init__(self, title, columns, rows=(), note=""):
        self.title = title
        self.columns = list(columns)
        self.rows = [list(r) for r in rows]
        self.note = note

    def add(self, *cells):
        self.rows.append(list(cells))

    def to_csv(self):
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(self.columns)
        writer.writerows([[format_value(c, csv=True) for c in row] for row in self.rows])
        return buffer.getvalue()

    def to_markdown(self):
        lines = [f"**{self.title}**", "", "| " + " | ".join(self.columns) + " |",
                 "|" + "|".join("---" for _ in self.columns) + "|"]
        lines += ["| " + " | ".join(format_value(c) for c in row) + " |" for row in self.rows]
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines) + "\n"


def format_value(value, csv=False):
    """Numbers with 4 significant digits (full precision in CSV); other cells as text."""
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "nan"
        return repr(float(value)) if csv else f"{value:.4g}"
    return str(value)


def save_figure(figure, path):
    """Write a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(figure)
    atomic_write_bytes(path, buffer.getvalue())


def write_outputs(out_dir, table, figure=None):
    """Write table.csv, table.md (and figure.png) into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "table.csv", out_dir / "table.md"]
    atomic_write_text(paths[0], table.to_csv())
    atomic_write_text(paths[1], table.to_markdown())
    if figure is not None:
        paths.append(out_dir / "figure.png")
        save_figure(figure, paths[-1])
    return paths
