"""A sweep's plots: median miss against each swept value (lines) and over each swept pair (heat maps).

One figure per axis and one per pair of axes, one panel per controller; the median runs over the
seeds and over the values of the axes not shown. matplotlib is imported when called.
"""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from fcmpc.montecarlo.sweep import SweepAxis

__all__ = ["plot_sweep"]


def _median(rows: list[dict], **where) -> float:
    miss = [r["remaining_km"] for r in rows if all(r[k] == v for k, v in where.items())]
    return float(np.median(miss)) if miss else float("nan")


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def plot_sweep(out: Path, rows: list[dict], axes: tuple[SweepAxis, ...]) -> list[Path]:
    """Write the line and heat-map figures under ``out``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    written = []
    for axis in axes:
        fig, ax = plt.subplots(figsize=(6, 4))
        for controller in controllers:
            ax.plot(axis.values, [_median(rows, controller=controller, **{axis.name: v}) for v in axis.values],
                    "o-", label=controller)
        ax.set_xlabel(axis.name)
        ax.set_ylabel("median miss (km)")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        ax.set_title(f"median miss against {axis.name}", fontsize=10)
        fig.tight_layout()
        written.append(out / f"line_{_safe(axis.name)}.png")
        fig.savefig(written[-1], dpi=110)
        plt.close(fig)
    for first, second in itertools.combinations(axes, 2):
        fig, panels = plt.subplots(1, len(controllers), figsize=(4.5 * len(controllers), 4), squeeze=False)
        for ax, controller in zip(panels[0], controllers):
            grid = np.array([[_median(rows, controller=controller, **{first.name: a, second.name: b})
                              for a in first.values] for b in second.values])
            image = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
            for (j, i), value in np.ndenumerate(grid):
                ax.text(i, j, f"{value:.2f}", ha="center", va="center", color="w", fontsize=8)
            ax.set_xticks(range(len(first.values)), [f"{v:g}" for v in first.values])
            ax.set_yticks(range(len(second.values)), [f"{v:g}" for v in second.values])
            ax.set_xlabel(first.name)
            ax.set_ylabel(second.name)
            ax.set_title(f"{controller}: median miss (km)", fontsize=10)
            fig.colorbar(image, ax=ax)
        fig.tight_layout()
        written.append(out / f"heatmap_{_safe(first.name)}_x_{_safe(second.name)}.png")
        fig.savefig(written[-1], dpi=110)
        plt.close(fig)
    return written
