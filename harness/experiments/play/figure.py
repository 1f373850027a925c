"""The success-rate bar chart of ``rt2 play``: one bar per configuration with its Wilson 95 % interval."""

from __future__ import annotations

from pathlib import Path

from harness.common.outputs import atomic_path

__all__ = ["draw"]


def draw(rows: list[dict], stem: Path, *, title: str = "") -> list[Path]:
    """Bars of ``success_rate`` with ``ci_low``..``ci_high`` error bars; writes stem.png and stem.pdf."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    labels = [f"{r['tracker']}\n{r['filter']}\n{r['rate_hz']:.0f} Hz" for r in rows]
    rate = [100 * r["success_rate"] for r in rows]
    err = [[100 * (r["success_rate"] - r["ci_low"]) for r in rows], [100 * (r["ci_high"] - r["success_rate"]) for r in rows]]
    colours = ["tab:red" if r["tracker"].startswith("rt2") else "tab:blue" for r in rows]
    fig, ax = plt.subplots(figsize=(1.6 + 1.5 * len(rows), 3.6))
    ax.bar(range(len(rows)), rate, yerr=err, capsize=5, color=colours, alpha=0.8)
    for i, r in enumerate(rows):
        ax.text(i, 2, f"{r['successes']}/{r['balls']}", ha="center", va="bottom", fontsize=8, color="white")
    ax.axhline(70, color="grey", lw=0.8, ls="--")
    ax.text(len(rows) - 0.5, 71, "paper: RT2 70 %", ha="right", va="bottom", fontsize=7, color="grey")
    ax.set_xticks(range(len(rows)), labels, fontsize=8)
    ax.set_ylabel("success rate (%), Wilson 95 % CI")
    ax.set_ylim(0, 100)
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    out = [stem.with_suffix(".png"), stem.with_suffix(".pdf")]
    for p in out:
        with atomic_path(p, "figure") as tmp:  # never a half-written figure
            fig.savefig(tmp, dpi=150)
    plt.close(fig)
    return out
