"""The report's tables: one row builder per table, each cell formatted from the metrics the stages write."""
from __future__ import annotations

import html
import math

from stages.report.plots import num


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


def table(header: list[str], rows: list[list[str]], cls: str = "") -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in header)
    b = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>'
