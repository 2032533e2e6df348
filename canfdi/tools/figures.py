"""The look the HTML reports share (`canfdi report`, the fleet report of `canfdi fleet`).

One figure factory (matplotlib's object API with the Agg canvas: no display, no pyplot global
state, safe in worker threads), one legend placement, one style sheet, so every page canfdi
writes looks alike. matplotlib is imported inside the functions: never on the monitor's path.
"""

from __future__ import annotations

__all__ = ["CSS", "LEGEND_OUTSIDE", "new_figure"]

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1250px; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.92em; }
th, td { border: 1px solid #bbb; padding: 0.3em 0.6em; text-align: left; vertical-align: top; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
.note { color: #8a4b00; }
code { background: #f4f4f4; padding: 0 0.2em; }
"""
"""The style sheet of every canfdi HTML page (inlined: the pages need no other file)."""

LEGEND_OUTSIDE = {"loc": "upper left", "bbox_to_anchor": (1.005, 1.0), "fontsize": 8,
                  "framealpha": 0.85}
"""``ax.legend(**LEGEND_OUTSIDE)``: the legend right of the axes, clear of the data."""


def new_figure(rows: int, cols: int = 1, height: float = 1.9, width: float = 11.0,
               sharex: bool = True):
    """A constrained-layout Figure of rows x cols gridded axes: (fig, axes (rows, cols)).

    ``height`` is per row (inches), the figure at least 3 inches tall; 100 dpi.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, max(3.0, 0.9 + height * rows)), layout="constrained", dpi=100)
    axes = fig.subplots(rows, cols, sharex=sharex, squeeze=False)
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    return fig, axes
