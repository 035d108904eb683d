"""Figures that show themselves: every figure the package returns is a matplotlib
``Figure`` (no pyplot, no global state) that Jupyter displays inline as a PNG, whatever
backend or ``%matplotlib`` magic the notebook has (IPython calls ``_repr_png_``)."""

from __future__ import annotations

import functools
import io

__all__ = ["new_figure"]

#: Resolution of the inline PNG (dots per inch).
INLINE_DPI = 100


@functools.cache
def _figure_class():
    from matplotlib.figure import Figure  # plotting is optional for the rest of the package

    class InlineFigure(Figure):
        """A matplotlib Figure with a PNG representation for IPython/Jupyter."""

        def _repr_png_(self) -> bytes:
            buffer = io.BytesIO()
            self.savefig(buffer, format="png", dpi=INLINE_DPI)
            return buffer.getvalue()

    return InlineFigure


def new_figure(**kwargs):
    """A new figure (``matplotlib.figure.Figure(**kwargs)``) that Jupyter shows inline."""
    return _figure_class()(**kwargs)
