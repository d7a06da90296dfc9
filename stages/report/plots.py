"""The report's plots: matplotlib figures rendered as inline, deterministic SVG (no date, stable ids)."""
from __future__ import annotations

import io
import math
import re


def num(x) -> float:
    """A CSV/JSON cell as float (missing, empty or None → NaN)."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def x_axis(rows: list[dict]) -> str:
    """The training-curve csv's x column: optimizer steps (older runs: epochs)."""
    return "step" if rows and "step" in rows[0] else "epoch"


def karras_plot(rows: list[dict]) -> str:
    """Position term per validation point: training (with noise and shifts) and the validation curve."""
    fig, ax = figure()
    xs = x_axis(rows)
    tr = [(num(r[xs]), num(r["position"])) for r in rows if r.get("position")]
    va = [(num(r[xs]), num(r["val_position"])) for r in rows if r.get("val_position")]
    if tr:
        ax.plot(*zip(*tr), label="training (position term)")
    if va:
        ax.plot(*zip(*va), marker=".", label="validation")
    ax.set_yscale("log")
    ax.set_xlabel("optimizer step" if xs == "step" else "epoch")
    ax.set_ylabel("position loss (px² per coordinate)")
    ax.legend()
    return svg(fig, "karras-loss")


def em_plot(rows: list[dict]) -> str:
    fig, ax = figure()
    for model in dict.fromkeys(r["model"] for r in rows):
        pts = [(num(r["iteration"]), num(r["log_posterior"])) for r in rows if r["model"] == model]
        ax.plot(*zip(*pts), marker=".", label=model)
    ax.set_xlabel("EM iteration")
    ax.set_ylabel("log posterior per frame")
    ax.legend()
    return svg(fig, "brand-em")


def svg(fig, name: str) -> str:
    """A matplotlib figure as an inline <svg> element (no XML header, stable ids, no date)."""
    import matplotlib
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": name, "svg.fonttype": "none"}):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None}, bbox_inches="tight")
    text = buf.getvalue()
    text = re.sub(r"\s*<metadata>.*?</metadata>", "", text, flags=re.S)    # RDF creator/date block
    return text[text.index("<svg"):]


def figure(w: float = 6.4, h: float = 3.2):
    from matplotlib.figure import Figure
    fig = Figure(figsize=(w, h))
    return fig, fig.add_subplot()


def loss_plot(rows: list[dict]) -> str:
    fig, ax = figure()
    models = sorted({r.get("model", "model") for r in rows})
    xs = x_axis(rows)
    for m in models:
        rs = [r for r in rows if r.get("model", "model") == m]
        x = [num(r[xs]) for r in rs]
        ax.plot(x, [num(r["train_loss"]) for r in rs], label=f"{m} train")
        ax.plot(x, [num(r["val_loss"]) for r in rs], "--", label=f"{m} validation")
    ax.set_xlabel("optimizer step" if xs == "step" else "epoch"), ax.set_ylabel("loss (PCA coefficients, MSE)"), ax.set_yscale("log")
    ax.grid(alpha=0.3), ax.legend(fontsize=8)
    return svg(fig, "loss")


def sweep_plot(rows: list[dict], paper_ms: float) -> str:
    fig, ax = figure()
    x = [num(r["delay_ms"]) for r in rows]
    ax.plot(x, [num(r["val_loss"]) for r in rows], "o-", label="validation loss")
    ax.axvline(paper_ms, color="tab:red", ls=":", label=f"paper: {paper_ms:g} ms")
    ax.set_xlabel("target delay (ms)"), ax.set_ylabel("validation loss")
    if rows and "val_mouth_error_px" in rows[0]:
        ax2 = ax.twinx()
        ax2.plot(x, [num(r["val_mouth_error_px"]) for r in rows], "s--", color="tab:green", label="mouth error (px)")
        ax2.set_ylabel("validation mouth error (px)")
    handles = [h for a in fig.axes for h in a.get_legend_handles_labels()[0]]
    ax.grid(alpha=0.3), ax.legend(handles=handles, loc="upper center", fontsize=8)
    return svg(fig, "sweep")


def opening_plot(rows: list[dict], clip: str) -> str:
    fig, ax = figure(7.0, 2.6)
    t = [num(r["time_s"]) for r in rows]
    ax.plot(t, [num(r["original_px"]) for r in rows], color="0.3", label="original (tracked)")
    ax.plot(t, [num(r["output_px"]) for r in rows], color="tab:orange", label="synthesized (re-tracked)")
    ax.set_xlabel("time (s)"), ax.set_ylabel("inner-lip opening (px)"), ax.set_title(clip, fontsize=9)
    ax.grid(alpha=0.3), ax.legend(fontsize=8)
    return svg(fig, f"opening-{clip}")


def voice_plot(cross: dict) -> str:
    """Median opening correlation at the best lag, per person (bars) and model (colours)."""
    models = list(cross.get("models", {}).values())
    people = sorted({g for r in models for g in r.get("groups", {})})
    fig, ax = figure(6.4, 3.0)
    width = 0.8 / max(len(models), 1)
    for i, r in enumerate(models):
        g = r.get("groups", {})
        xs = [j + (i - (len(models) - 1) / 2) * width for j in range(len(people))]
        ax.bar(xs, [num((g.get(p) or {}).get("median_corr_best")) for p in people], width, label=r.get("label", "?"))
        ax.plot(xs, [num((g.get(p) or {}).get("median_corr_lag0")) for p in people], "k_", ms=8)
    ax.set_xticks(range(len(people)), people), ax.set_ylabel("opening corr (bar: best lag; –: lag 0)")
    ax.set_ylim(-0.2, 1.0), ax.grid(alpha=0.3, axis="y"), ax.legend(fontsize=7)
    return svg(fig, "voices")
