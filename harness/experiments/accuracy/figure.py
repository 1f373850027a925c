"""The error histogram of the accuracy experiment, like the paper's Sec. 3.2 figure (PNG and PDF).

Left panel: the paper's view, a linear error axis from 0 to the 99.5th percentile of all errors (at
least 10 cm, at most 2 m, rounded up to 10 cm) in 80 bins, density (share of frames with a position per
cm) on a log axis so rare modes show, larger errors counted in the legend. Right panel: every error on a
logarithmic axis from 0.1 mm to the largest, so errors of metres (RTBlob's pair mismatches) are visible.
RT2 is red as in the paper (solid), the paper's RT2 dashed. Matplotlib with the Agg backend.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.common.outputs import atomic_path

__all__ = ["COLOURS", "plot_histogram"]

#: tracker -> line colour (RT2 red as in the paper) and style
COLOURS = {"rt2": "#d62728", "rt2-paper": "#ff7f0e", "rtblob": "#1f77b4"}
_STYLES = {"rt2-paper": "--"}


def plot_histogram(errors_m: dict, paths, *, title: str = "") -> list[Path]:
    """Draw the histogram of ``errors_m`` {tracker: (n,) metres, NaN = no position} into every path
    (the suffix picks the format: .png, .pdf); returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    fig, (ax_lin, ax_log) = plt.subplots(1, 2, figsize=(10.0, 4.0), constrained_layout=True)
    all_cm = np.concatenate([np.asarray(e, float)[np.isfinite(e)] * 100 for e in errors_m.values()] + [np.zeros(1)])
    top_cm = max(float(all_cm.max()) * 1.5, 20.0)
    log_bins = np.logspace(-2, np.log10(top_cm), 70)
    lin_max = float(np.clip(np.ceil(np.percentile(all_cm, 99.5) / 10.0) * 10.0, 10.0, 200.0))
    lin_bins = np.linspace(0.0, lin_max, 81)
    width = lin_bins[1] - lin_bins[0]
    for name, e in errors_m.items():
        e = np.asarray(e, float)
        cm = e[np.isfinite(e)] * 100.0
        colour, ls = COLOURS.get(name, None), _STYLES.get(name, "-")
        if cm.size == 0:
            ax_lin.plot([], [], color=colour, label=f"{name}: no position")
            continue
        over = float(np.mean(cm > lin_max))
        w = np.full(cm.size, 1.0 / cm.size)
        ax_lin.hist(cm[cm <= lin_max], bins=lin_bins, weights=w[cm <= lin_max] / width, histtype="step", lw=1.6,
                    color=colour, ls=ls, label=f"{name} (> {lin_max:.0f} cm: {100 * over:.2f} %)")
        ax_log.hist(np.maximum(cm, log_bins[0]), bins=log_bins, weights=w, histtype="step", lw=1.6, color=colour, ls=ls,
                    label=name)
    ax_lin.set(xlabel="error (cm)", ylabel="density (1/cm)", yscale="log", xlim=(0, lin_max))
    ax_lin.axvline(10.0, color="grey", ls=":", lw=1)
    ax_lin.legend(fontsize=8)
    ax_log.set(xlabel="error (cm, log scale)", ylabel="share of frames with a position", xscale="log", yscale="log")
    ax_log.axvline(10.0, color="grey", ls=":", lw=1)
    ax_log.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    for p in paths:
        with atomic_path(p, "figure") as tmp:  # never a half-written figure
            fig.savefig(tmp, dpi=130, metadata={"CreationDate": None} if p.suffix == ".pdf" else None)
    plt.close(fig)
    return paths
