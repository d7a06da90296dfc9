"""report — one self-contained HTML page of the results: ``report.out``/index.html.

What it shows, from the files the other stages write:

- the model families trained on this corpus (today ``train.model``: the LSTM) on the same
  validation frames, with their baselines as extra rows: mouth error (px, % IOD), ratio to the
  mean shape, opening correlation, share of clips within one frame (``train.metrics``);
- loss curves (``train.plots``) and the delay sweep (``delay_sweep.plots``) with the paper's
  200 ms marked (``report.paper_delay_ms``);
- the synthesized video's own quality (``evaluate.metrics``, paper Video J) and, for the
  evaluated clips (worst, median and best by mouth error when there are more than three), the
  inner-lip opening over time of the output against the original, and the diagnostic video
  (target | result | texture, H.264) copied next to the page;
- with ``report.benches`` (a folder of bench results; ``bench/report.py`` sets it): the
  ``lipsynth speak`` path beside the DVC path, and other people's voices per person and model;
- synthesis speed per phase from ``logs/*.timing.json`` when present (untracked: "not measured"
  otherwise), the params file, the git commit and the date.

Plots are inline SVG (matplotlib), videos are relative ``<video src>``: the folder works offline,
copied anywhere. Everything but the date/commit line and the timings is deterministic.

Run: ``python -m stages.report.report`` (the DVC stage) or ``lipsynth report [--params P] [--open]``.
"""
from __future__ import annotations

import argparse
import csv
import datetime as _dt
import html
import io
import json
import logging
import math
import re
import shutil
import subprocess
from pathlib import Path

from pipeline.params import Params, as_dict, load_params
from pipeline.io.runner import run_main, setup_logging
from pipeline.io.store import atomic_output

log = logging.getLogger("lipsynth.report")
TIMING_LOGS = ("synthesize", "composite", "evaluate", "train_karras", "render_mesh")


# ---------------------------------------------------------------- reading inputs

def read_json(path) -> dict | None:
    p = Path(path)
    return json.loads(p.read_text()) if p.is_file() else None


def read_csv(path) -> list[dict]:
    p = Path(path)
    if not p.is_file():
        return []
    with open(p, newline="") as f:
        return list(csv.DictReader(f))


def num(x) -> float:
    """A CSV/JSON cell as float (missing, empty or None → NaN)."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def git_commit(root: Path) -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown (no git)"
    return (head or "unknown (not a git checkout)") + (" + uncommitted changes" if head and dirty else "")


# ---------------------------------------------------------------- tables

def fmt(x, digits: int = 2, pct: bool = False) -> str:
    v = num(x)
    if not math.isfinite(v):
        return "—"
    return f"{100 * v:.0f}%" if pct else f"{v:.{digits}f}"


def model_rows(train: dict | None) -> list[list[str]]:
    """Rows of the model-family table from one ``train.metrics`` file: the model, then its baselines."""
    if not train:
        return []
    rows = []

    def row(name, m, ratio):
        rows.append([name, fmt(m.get("mouth_error_px")), fmt(m.get("mouth_error_iod_pct")), fmt(ratio),
                     fmt(m.get("median_opening_corr"), 3), fmt(m.get("av_within_one_frame"), pct=True),
                     str(m.get("n_clips", "—"))])
    mean_px = num((train.get("baseline_mean_shape") or {}).get("mouth_error_px"))
    model = train.get("model", "model")
    row(f"{model} (delay {int(num(train.get('delay_steps', 0))) * 10} ms)", train.get("val", {}),
        train.get("ratio_to_mean_shape"))
    for key, name in (("baseline_lstm_delay0", f"baseline: {model}, delay 0"),
                      ("baseline_mean_shape", "baseline: mean shape")):
        if key in train:
            b = train[key]
            row(name, b, num(b.get("mouth_error_px")) / mean_px if mean_px else math.nan)
    return rows


def brand_rows(brand: dict | None, mean_px: float) -> list[list[str]]:
    """Model-family rows of Voice Puppetry (``brand.metrics``): the entropic HMM and the ML baseline."""
    rows = []
    for key, name in (("entropic", "Voice Puppetry (entropic HMM)"), ("ml", "baseline: maximum-likelihood HMM")):
        m = (brand or {}).get(key, {}).get("val")
        if m:
            px = num(m.get("mouth_error_px"))
            rows.append([name, fmt(px), fmt(m.get("mouth_error_iod_pct")), fmt(px / mean_px if mean_px else math.nan),
                         fmt(m.get("median_opening_corr"), 3), fmt(m.get("av_within_one_frame"), pct=True),
                         str(m.get("n_clips", "—"))])
    return rows


def karras_rows(karras: dict | None, mean_px: float) -> list[list[str]]:
    """The Karras et al. row (``karras.metrics``): default emotion, two inferences 4 ms apart."""
    m = (karras or {}).get("val")
    if not m:
        return []
    px = num(m.get("mouth_error_px"))
    name = f"Karras et al. ({fmt(num(karras.get('training_seconds')) / 60, 1)} min, {budget_text(karras)})"
    return [[name, fmt(px), fmt(m.get("mouth_error_iod_pct")), fmt(px / mean_px if mean_px else math.nan),
             fmt(m.get("median_opening_corr"), 3), fmt(m.get("av_within_one_frame"), pct=True),
             str(m.get("n_clips", "—"))]]


def budget_text(m: dict) -> str:
    """'240 steps (10.0 epochs)' from a metrics dict (older runs recorded epochs only)."""
    if m.get("steps_run") is None:
        return f"{m.get('epochs')} epochs"
    kept = f", weights of step {m['step_kept']}" if m.get("step_kept") not in (None, m["steps_run"]) else ""
    return f"{m['steps_run']} steps ({fmt(num(m.get('epochs')), 1)} epochs{kept})"


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


PAPER_002 = {"entropic": dict(eq7_face=(0.1255, 0.1698), eq7_voice=(0.1731, 0.2115), entropy=0.0315, perplexity=2.08),
             "ml": dict(entropy=0.875)}


def brand_paper_rows(brand: dict | None) -> list[list[str]]:
    """The paper's §5 measures beside ours: Eq. 7 error train/test from the face's states and from
    the voice, entropy rate of the decoded state sequence, transition perplexity, states/transitions."""
    rows = []
    for key, name in (("entropic", "entropic"), ("ml", "maximum likelihood")):
        m = (brand or {}).get(key)
        if not m:
            continue
        eq = m.get("eq7", {})
        paper = PAPER_002.get(key, {})
        pf, pv = paper.get("eq7_face"), paper.get("eq7_voice")
        rows.append([name, f"{fmt(eq.get('state_sequence', {}).get('train'), 3)} / "
                           f"{fmt(eq.get('state_sequence', {}).get('test'), 3)}"
                           + (f" (paper {pf[0]} / {pf[1]})" if pf else ""),
                     f"{fmt(eq.get('voice', {}).get('train'), 3)} / {fmt(eq.get('voice', {}).get('test'), 3)}"
                     + (f" (paper {pv[0]} / {pv[1]})" if pv else ""),
                     fmt(m.get("entropy_rate_nats"), 3) + (f" (paper {paper['entropy']})" if "entropy" in paper else ""),
                     fmt(m.get("transition_perplexity"), 2) + (f" (paper {paper['perplexity']})" if "perplexity" in paper else ""),
                     f"{m.get('states', '—')} / {m.get('transitions', '—')}"])
    return rows


def em_plot(rows: list[dict]) -> str:
    fig, ax = figure()
    for model in dict.fromkeys(r["model"] for r in rows):
        pts = [(num(r["iteration"]), num(r["log_posterior"])) for r in rows if r["model"] == model]
        ax.plot(*zip(*pts), marker=".", label=model)
    ax.set_xlabel("EM iteration")
    ax.set_ylabel("log posterior per frame")
    ax.legend()
    return svg(fig, "brand-em")


EVAL_COLUMNS = [("mouth error (px)", "mouth_error_px", 2), ("% IOD", "mouth_error_iod_pct", 2),
                ("static mouth (px)", "static_mouth_error_px", 2), ("error / static", "error_ratio", 2),
                ("opening corr", "opening_corr", 3), ("best lag (frames)", "opening_best_lag", 0),
                ("sharpness ratio", "sharpness_ratio", 2), ("flicker ratio", "flicker_ratio", 2),
                ("mouth MAD", "mouth_mad", 1), ("frames fallen back", "fallen_back", 0)]


def evaluate_rows(ev: dict | None) -> list[list[str]]:
    """Per-clip rows and a median row of ``evaluate.metrics``."""
    if not ev:
        return []
    rows = []
    for c in ev.get("per_clip", []):
        c = dict(c, error_ratio=num(c.get("mouth_error_px")) / num(c.get("static_mouth_error_px")))
        rows.append([c.get("clip", "?")] + [fmt(c.get(k), d) for _, k, d in EVAL_COLUMNS])
    med = ev.get("median") or {}
    if med:
        rows.append(["median"] + [fmt(med.get(k), d) if k in med else "" for _, k, d in EVAL_COLUMNS])
    return rows


def shown_clips(per_clip: list[dict]) -> list[tuple[str, dict]]:
    """All clips when ≤ 3, else the worst, median and best by mouth error, labelled."""
    if len(per_clip) <= 3:
        return [("", c) for c in per_clip]
    s = sorted(per_clip, key=lambda c: num(c.get("mouth_error_px")))
    return [("worst", s[-1]), ("median", s[len(s) // 2]), ("best", s[0])]


def table(header: list[str], rows: list[list[str]], cls: str = "") -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in header)
    b = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>'


def timing_tables(logs: dict[str, dict | None]) -> str:
    out = []
    for name, t in logs.items():
        if not t:
            out.append(f"<p><b>{html.escape(name)}</b>: not measured (no logs/{html.escape(name)}.timing.json)</p>")
            continue
        unit = {"evaluate": "s per clip", "train_karras": "seconds, or as named"}.get(
            name, "ms per frame (thread time) or as named")
        rows = [[k, fmt(v, 2)] for k, v in t.items()]
        out.append(f"<h3>{html.escape(name)} <small>({unit})</small></h3>" + table(["phase", "value"], rows, "timing"))
    return "\n".join(out)


# ---------------------------------------------------------------- plots (inline SVG)

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


def voice_rows(cross: dict) -> list[list[str]]:
    """Rows of the other-voices table (``bench/cross_speaker.py``'s json): per model, per person."""
    rows = []
    for r in cross.get("models", {}).values():
        for person, g in r.get("groups", {}).items():
            rows.append([r.get("label", "?"), person, str(g.get("n")), fmt(g.get("median_corr_lag0")),
                         fmt(g.get("median_corr_best")), fmt(g.get("within_one_frame"), pct=True),
                         f"{num(g.get('median_source_offset')):+.0f}", fmt(g.get("median_corr_source_lag"))])
        u = r.get("unseen")
        if u and r.get("unseen_people") and len(r["unseen_people"]) < len(r.get("groups", {})):
            rows.append([r.get("label", "?"), "unseen by every model: " + ", ".join(r["unseen_people"]), str(u.get("n")),
                         fmt(u.get("median_corr_lag0")), fmt(u.get("median_corr_best")),
                         fmt(u.get("within_one_frame"), pct=True), "—", "—"])
        d = r.get("in_domain") or {}
        rows.append([r.get("label", "?"), f"all {r.get('core_clips')} core clips", str(r.get("core_clips")),
                     fmt(r.get("median_corr_lag0")), fmt(r.get("median_corr_best")),
                     fmt(r.get("within_one_frame"), pct=True), "—", fmt(r.get("median_corr_source_lag")) +
                     (f" (in-domain {fmt(d.get('mouth_error_iod_pct'), 3)} % IOD)" if d else "")])
    return rows


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


PATH_COLUMNS = (("mouth error (px)", "mouth_error_px", 3), ("ratio to static mouth", "error_ratio", 2),
                ("opening corr", "opening_corr", 3), ("within one frame", "within_1_frame", None),
                ("sharpness ratio", "sharpness_ratio", 2), ("flicker ratio", "flicker_ratio", 2))


def path_rows(quality: dict[str, dict | None]) -> list[list[str]]:
    """One row per synthesis path (``bench/synthesis_quality.py`` jsons): medians over its clips."""
    rows = []
    for label, q in quality.items():
        if q:
            m = q.get("median", {})
            rows.append([label, str(q.get("clips"))] + [fmt(m.get(k), d or 2, pct=d is None) for _, k, d in PATH_COLUMNS])
    return rows


# ---------------------------------------------------------------- the page

CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
td:first-child,th:first-child{text-align:left}tr:last-child td{font-weight:600}
table.timing tr:last-child td,table.brand tr:last-child td{font-weight:normal}
.plot svg{max-width:100%;height:auto}.clip{margin:1em 0;padding:.5em;border:1px solid #eee}
video{max-width:100%;background:#000}pre{background:#f6f6f6;padding:.8em;overflow:auto;font-size:.8em}
.meta{color:#666;font-size:.85em}
"""


def build_html(ctx: dict) -> str:
    """The page from gathered inputs (pure: no file access). ``ctx`` keys: title, train, loss_rows,
    sweep_rows, paper_delay_ms, evaluate, clips [(label, clip dict, opening rows, video src, duration)],
    timings {name: dict|None}, params_text, commit, date."""
    e = html.escape
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{e(ctx['title'])}</title>"
             f"<style>{CSS}</style></head><body>", f"<h1>{e(ctx['title'])}</h1>",
             f"<p class=\"meta\" id=\"meta\">commit {e(ctx['commit'])} · generated {e(ctx['date'])}</p>"]
    parts.append("<h2>Audio → mouth shape: model families</h2>")
    rows = model_rows(ctx.get("train"))
    mean_px = num(((ctx.get("train") or {}).get("baseline_mean_shape") or {}).get("mouth_error_px"))
    rows[1:1] = brand_rows(ctx.get("brand"), mean_px) + karras_rows(ctx.get("karras"), mean_px)
    if rows:
        parts.append("<p>Validation videos (held out by video), lip landmarks predicted from audio against the "
                     "tracked ones.</p>")
        parts.append(table(["model", "mouth error (px)", "% IOD", "ratio to mean shape", "opening corr",
                            "within one frame", "clips"], rows, "models"))
    else:
        parts.append("<p>No training metrics (run <code>dvc repro train</code>).</p>")
    parts.append("<h2>Training</h2>")
    if ctx.get("loss_rows"):
        parts.append(f"<h3>Loss curves</h3><div class=\"plot\" id=\"plot-loss\">{loss_plot(ctx['loss_rows'])}</div>")
    if ctx.get("sweep_rows"):
        parts.append("<h3>Delay sweep (paper Fig. 9a)</h3><div class=\"plot\" id=\"plot-sweep\">"
                     f"{sweep_plot(ctx['sweep_rows'], ctx.get('paper_delay_ms', 200.0))}</div>")
    if ctx.get("brand"):
        b = ctx["brand"]
        parts.append("<h3>Voice Puppetry (paper 002 §5)</h3>"
                     f"<p>{b.get('states_initial')} initial states, face {b.get('face_dims')} PCA coordinates "
                     f"({100 * num(b.get('face_variance_kept')):.0f}% of the variance) + velocities, voice features "
                     f"<code>{e(str(b.get('features')))}</code> at {fmt(b.get('rate'), 1)} Hz; "
                     f"{b.get('training_frames')} training frames. Eq. 7 error = Σ‖x−y‖² / Σ‖x+y‖² of face points "
                     "about the mean face per clip, averaged over clips.</p>")
        parts.append(table(["HMM", "Eq. 7 from face states (train / test)", "Eq. 7 from voice (train / test)",
                            "entropy rate (nats/frame)", "transition perplexity", "states / transitions"],
                           brand_paper_rows(b), "brand"))
        if ctx.get("brand_rows"):
            parts.append(f"<div class=\"plot\" id=\"plot-brand\">{em_plot(ctx['brand_rows'])}</div>")
    if ctx.get("karras"):
        k = ctx["karras"]
        em = k.get("emotions") or {}
        parts.append("<h3>Karras et al. (paper 001)</h3>"
                     f"<p>{k.get('training_videos')} training videos ({fmt(num(k.get('training_seconds')) / 60, 1)} min, "
                     f"{k.get('training_frames')} frames), {budget_text(k)} (time per step: the train_karras "
                     "timing below); 42 lower-face points (jaw, nose, lips). "
                     f"Emotion mining (§5.1): {em.get('step1', '—')} of {em.get('scanned', '—')} scanned vectors pass "
                     f"the closed/open probes, {em.get('step2', '—')} survive playback → "
                     f"{k.get('emotion_candidates')} candidates (<code>lipsynth emotions</code>).</p>")
        if ctx.get("karras_rows"):
            parts.append(f"<div class=\"plot\" id=\"plot-karras\">{karras_plot(ctx['karras_rows'])}</div>")
    parts.append("<h2>Audio → video: the synthesized video against the original (Video J)</h2>")
    ev = ctx.get("evaluate")
    if ev:
        parts.append(f"<p>{e(str(ev.get('setting', '')))}; candidates "
                     f"{'only from other videos' if ev.get('exclude_target_from_pool') else 'include the target'}; "
                     f"{ev.get('clips', 0)} validation clip(s). Ratios are output / original.</p>")
        parts.append(table(["clip"] + [c for c, _, _ in EVAL_COLUMNS], evaluate_rows(ev), "evaluate"))
    else:
        parts.append("<p>Not evaluated (run <code>dvc repro evaluate</code>).</p>")
    for label, clip, opening, src, duration in ctx.get("clips", []):
        name = clip.get("clip", "?")
        parts.append(f"<div class=\"clip\"><h3>{e(name)}{(' — ' + e(label)) if label else ''}: mouth error "
                     f"{fmt(clip.get('mouth_error_px'))} px, opening corr {fmt(clip.get('opening_corr'), 3)}</h3>")
        if opening:
            parts.append(f"<div class=\"plot\">{opening_plot(opening, name)}</div>")
        if src:
            parts.append(f"<video controls muted preload=\"auto\" src=\"{e(src)}\" data-duration=\"{duration:.3f}\">"
                         "</video><p class=\"meta\">target | result | synthesized texture</p>")
        parts.append("</div>")
    if any((ctx.get("paths") or {}).values()):
        parts.append("<h2>The DVC path and the <code>lipsynth speak</code> path</h2><p>The same validation clips "
                     "synthesized (no re-timing) through the stages and through <code>lipsynth speak</code> on the clip "
                     "files (each clip's own audio into its own video), medians over clips "
                     "(<code>bench/synthesis_quality.py</code>).</p>")
        parts.append(table(["path", "clips"] + [c for c, _, _ in PATH_COLUMNS], path_rows(ctx["paths"]), "paths"))
    if ctx.get("voices"):
        parts.append("<h2>Other voices (people the models never saw)</h2><p>Per clip, the inner-lip opening predicted "
                     "from the clip's own audio against the opening tracked on the clip; median Pearson correlation at "
                     "lag 0 and at the best lag within ±5 frames, share of clips whose best lag is within one frame, "
                     "and the source clip's own audio–video offset (speech envelope against the tracked opening, no "
                     "model) with the correlation at that offset (<code>bench/cross_speaker.py</code>).</p>")
        parts.append(table(["model (front end)", "person", "clips", "corr lag 0", "corr best lag", "within one frame",
                            "source offset (frames)", "corr at source offset"], voice_rows(ctx["voices"]), "voices"))
        parts.append(f"<div class=\"plot\" id=\"plot-voices\">{voice_plot(ctx['voices'])}</div>")
    parts.append("<h2>Synthesis speed</h2>" + timing_tables(ctx.get("timings", {})))
    parts.append(f"<h2>Parameters</h2><pre id=\"params\">{e(ctx.get('params_text', ''))}</pre>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def gather(params: Params, params_file: Path, root: Path = Path(".")) -> tuple[dict, list[tuple[Path, str]]]:
    """The page's inputs and the files to copy next to it (source, relative name)."""
    ev = read_json(root / params.evaluate.metrics)
    ev_dir = root / params.evaluate.out
    clips, copies = [], []
    for label, c in shown_clips((ev or {}).get("per_clip", [])):
        video = c.get("diagnostic_video") or c.get("video")
        src = None
        if video and (ev_dir / video).is_file():
            src = f"videos/{video}"
            copies.append((ev_dir / video, src))
        opening = read_csv(ev_dir / c["opening_csv"]) if c.get("opening_csv") else []
        clips.append((label, c, opening, src, num(c.get("frames")) / num(c.get("fps", 25.0))))
    ctx = dict(title=params.report.title, train=read_json(root / params.train.metrics),
               brand=read_json(root / params.brand.metrics), brand_rows=read_csv(root / params.brand.plots),
               karras=read_json(root / params.karras.metrics), karras_rows=read_csv(root / params.karras.plots),
               loss_rows=read_csv(root / params.train.plots), sweep_rows=read_csv(root / params.delay_sweep.plots),
               paper_delay_ms=params.report.paper_delay_ms, evaluate=ev, clips=clips,
               timings={n: read_json(root / "logs" / f"{n}.timing.json") for n in TIMING_LOGS},
               params_text=shown_params(params), commit=git_commit(root), **benches(params.report.benches, root),
               date=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"))
    return ctx, copies


def benches(folder: str | None, root: Path) -> dict:
    """Bench results shown when ``report.benches`` names their folder (``bench/report.py`` does):
    cross_speaker.json and the synthesis-quality jsons of the DVC and the speak paths."""
    if not folder:
        return {}
    d = root / folder
    return dict(voices=read_json(d / "cross_speaker.json"),
                paths={"DVC stages (candidates from other videos)": read_json(d / "synthesis_quality.json"),
                       "DVC stages (target's own frames in the pool)": read_json(d / "synthesis_quality_target_in_pool.json"),
                       "lipsynth speak (clip files)": read_json(d / "synthesis_quality_speak.json")})


SHOWN_SECTIONS = ("synthetic_speaker", "data", "ingest", "landmarks", "frontalize", "pca", "train", "brand", "karras", "delay_sweep",
                  "synthesize", "composite", "speak", "evaluate", "report")     # all but `cluster` (no effect on results)


def shown_params(params: Params) -> str:
    """The params that produced the page, as YAML (the sections the stage declares in dvc.yaml)."""
    import yaml
    tree = as_dict(params)
    return yaml.safe_dump({k: tree[k] for k in SHOWN_SECTIONS if k in tree}, sort_keys=False, allow_unicode=True)


def write_report(params: Params, params_file: Path) -> Path:
    """Write ``report.out``/index.html and its videos atomically; returns the page's path."""
    ctx, copies = gather(params, params_file)
    with atomic_output(params.report.out) as tmp:
        tmp.mkdir(parents=True)
        for source, rel in copies:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, tmp / rel)
        (tmp / "index.html").write_text(build_html(ctx))
    page = Path(params.report.out) / "index.html"
    log.info("wrote %s (%.1f kB page, %d videos)", page, page.stat().st_size / 1e3, len(copies))
    return page


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth report", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    ap.add_argument("--open", action="store_true", help="open the page in a web browser")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)

    def go():
        page = write_report(load_params(a.params), Path(a.params)).absolute()
        print(page)
        if a.open:
            import webbrowser
            webbrowser.open(page.as_uri())
    return run_main(go)


if __name__ == "__main__":
    raise SystemExit(main())
