"""The stabilisation chart as a PNG (matplotlib, Agg backend: no display needed; imported only when drawn).

The usual layout (Peeters et al. 2004, fig. 2): model order against frequency, one marker per pole by its
stability label, the sum of the FRF magnitudes behind it on a log axis so the peaks line up with the
columns of stable poles, and the selected poles circled.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.modal_id import LABELS, StabTable

_STYLE = {"o": ("x", "0.7", "new"), "f": ("_", "tab:blue", "f stable"), "d": ("^", "tab:orange", "f, damping"),
          "v": ("v", "tab:purple", "f, vector"), "s": ("s", "tab:green", "stable (f, damping, vector)")}


def stabilisation_png(
    table: StabTable, path: str | Path, freq: np.ndarray | None = None, H: np.ndarray | None = None,
    selected: np.ndarray | None = None, title: str = "Stabilisation chart",
) -> Path:
    """Draw ``table`` (and ``sum |H|`` over outputs and references, if given) to ``path``; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 6), dpi=100)
    try:
        f = table.freq_hz
        for code, label in enumerate(LABELS):
            k = table.status == code
            marker, color, name = _STYLE[label]
            ax.scatter(f[k], table.order[k], marker=marker, s=14, c=color, label=f"{label}: {name}", linewidths=1)
        if selected is not None and len(selected):
            ax.scatter(f[selected], table.order[selected], s=120, facecolors="none", edgecolors="red", label="selected")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("model order")
        ax.set_title(title)
        if freq is not None and H is not None:
            ax2 = ax.twinx()
            ax2.semilogy(freq, np.sum(np.abs(H), axis=(0, 1)), color="0.3", lw=0.8)
            ax2.set_ylabel("sum |H|")
        ax.legend(loc="upper left", fontsize=7)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return Path(path)


__all__ = ["stabilisation_png"]
