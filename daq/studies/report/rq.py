"""The near-live analysis against time and energy: RQ per NNM with the IR events, modal energies, and the RQ-FEP.

The RQ-FEP (RQ frequency against windowed total modal energy, seed Ch. 4) is the session's own frequency–energy
plot: the same windows as the RQ curves, placed on the energy axis (``daq.view.recording.rqfep_points``).
"""

from __future__ import annotations

import numpy as np

from daq.studies.report.page import png


def rq_figure(rq: list[dict], modal: list[dict], ir: list[dict]) -> tuple[str, str] | None:
    """``(title, PNG)`` of RQ per NNM (IR events shaded) above the modal energies; None without either."""
    import matplotlib.pyplot as plt

    if not (rq or modal):
        return None
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    if rq:
        _rq_curves(axes[0], rq)
    for e in ir:
        for ax in axes:
            ax.axvspan(e["start_s"], e["end_s"], color="tab:purple", alpha=0.15)
        axes[0].annotate(f"IR {e.get('id', '')} {e.get('ratio', '')}", (e["start_s"], e.get("f_recv_hz", 1.0)), fontsize=7)
    axes[0].set_ylabel("RQ frequency [Hz]")
    axes[0].set_title("RQ per NNM (base grid windows); IR events shaded")
    if modal:
        _modal_energies(axes[1], modal)
    axes[1].set_ylabel("modal energy [J]")
    axes[1].set_xlabel("time [s]")
    return "RQ and modal energies", png(fig)


def _rq_curves(ax, rq: list[dict]) -> None:
    """Each NNM's RQ frequency at the end of its window, log scale."""
    t = np.array([r["t_end_s"] for r in rq])
    f = np.array([r["rq_hz"] for r in rq], float)
    for k in range(f.shape[1]):
        ax.plot(t, f[:, k], ".", ms=2, label=f"NNM{k + 1}")
    ax.set_yscale("log")
    ax.legend(fontsize=7, loc="upper right")


def _modal_energies(ax, modal: list[dict]) -> None:
    """Each mode's energy against time, log scale (a zero is a gap, not minus infinity)."""
    tm = np.array([m["t_end_s"] for m in modal])
    e = np.array([m["modal_energy_J"] for m in modal], float)
    for k in range(e.shape[1]):
        ax.semilogy(tm, np.where(e[:, k] > 0, e[:, k], np.nan), lw=0.8, label=f"mode {k + 1}")
    ax.legend(fontsize=7, loc="upper right")


def rqfep_figure(rq: list[dict], modal: list[dict]) -> tuple[str, str] | None:
    """``(title, PNG)`` of the RQ-FEP; None without both RQ and modal energies, or with no window on both."""
    if not (rq and modal):
        return None
    import matplotlib.pyplot as plt

    from daq.view.setup import rqfep_points

    tm = np.array([m["t_end_s"] for m in modal])
    et = np.array([np.nansum(m["modal_energy_J"]) for m in modal])
    _t, le, f = rqfep_points(rq, tm, et)
    if not f.size:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for k in range(f.shape[1]):
        ax.semilogx(10.0**le, f[:, k], ".", ms=3, label=f"NNM{k + 1}")
    ax.set_yscale("log")
    ax.set_xlabel("windowed total modal energy [J]")
    ax.set_ylabel("RQ frequency [Hz]")
    ax.set_title("RQ-FEP (RQ frequency against energy)")
    ax.legend(fontsize=7)
    return "RQ-FEP", png(fig)
