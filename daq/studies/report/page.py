"""What every section of ``gvt report`` draws with: a figure as an embedded PNG, a titled HTML table, a num.

The report is one self-contained HTML file, so a figure is a base64 data URI (no external asset, no network)
and every cell is escaped text. The sections import these from here, below them all, and never from the
assembly (``build.py``), so no section depends on another's module to be drawn.
"""

from __future__ import annotations

import base64
import html
import io


def png(fig, dpi: float = 90.0) -> str:
    """The figure as a PNG data URI, drawn exactly once.

    Why not ``fig.savefig``: with ``bbox_inches="tight"`` (what this used) or with any layout engine,
    ``FigureCanvasBase.print_figure`` draws the whole figure once to measure it and then again to write
    it, so every report figure was drawn twice (counted in tests/test_report.py). Here the constrained
    layout engine runs inside the single ``Figure.draw`` (where it runs on screen too: matplotlib's
    "Constrained layout guide") and the Agg buffer is encoded as the PNG ``savefig`` would write
    (``backend_agg.print_png`` does the same ``imsave`` of ``buffer_rgba``)."""
    import matplotlib.image as mimage
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if fig.get_layout_engine() is None:
        fig.set_layout_engine("constrained")
    fig.set_dpi(dpi)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    buf = io.BytesIO()
    mimage.imsave(buf, canvas.buffer_rgba(), format="png", dpi=dpi)
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def table(title: str, cols: list[str], rows: list[list], empty: str = "none") -> str:
    """``<h2>title</h2>`` and the table, or ``empty`` said in italics: a section without rows still says so."""
    h = f"<h2>{html.escape(title)}</h2>"
    if not rows:
        return h + f"<p class='none'>{html.escape(empty)}</p>"
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in r) + "</tr>" for r in rows)
    return h + f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def num(x, fmt: str = ".3f") -> str:
    """``x`` formatted, or a dash when the record lacks it (a missing key is ``None``, not a failed report)."""
    try:
        return format(float(x), fmt)
    except (TypeError, ValueError):
        return "—"
