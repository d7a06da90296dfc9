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
- with the 3D head's glTF (``render_mesh.export``/head.glb): an interactive three.js viewer of it,
  played in sync with its audio (``pipeline.face.gltf_viewer``; assets in ``head/``);
- the params file. Not the date, the commit or the last run's timings (``logs/*.timing.json``): the page is
  the same bytes on every run and machine, so ``dvc repro`` on a fresh clone reproduces its hash.

Plots are inline SVG (matplotlib), videos are relative ``<video src>``: the folder works offline,
copied anywhere.

Run: ``python -m stages.report.report`` (the DVC stage) or ``lipsynth report [--params P] [--open]``.
"""
from __future__ import annotations

import argparse
import csv
import html
import json
import logging
import shutil
from pathlib import Path

from pipeline.face import gltf_viewer
from pipeline.params import Params, as_dict, load_params
from pipeline.io.runner import run_main, setup_logging
from pipeline.io.store import atomic_output
from stages.report.tables import (EVAL_COLUMNS, PATH_COLUMNS, brand_paper_rows, brand_rows, budget_text, evaluate_rows, fmt,
                                   karras_rows, model_rows, path_rows, table, voice_rows)
from stages.report.plots import (em_plot, karras_plot, loss_plot, num, opening_plot, sweep_plot,
                                  voice_plot)

log = logging.getLogger("lipsynth.report")


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


# ---------------------------------------------------------------- tables


def shown_clips(per_clip: list[dict]) -> list[tuple[str, dict]]:
    """All clips when ≤ 3, else the worst, median and best by mouth error, labelled."""
    if len(per_clip) <= 3:
        return [("", c) for c in per_clip]
    s = sorted(per_clip, key=lambda c: num(c.get("mouth_error_px")))
    return [("worst", s[-1]), ("median", s[len(s) // 2]), ("best", s[0])]


# ---------------------------------------------------------------- plots (inline SVG)


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
    params_text. Nothing on the page depends on when or where it was made."""
    e = html.escape
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{e(ctx['title'])}</title>"
             f"<style>{CSS}</style></head><body>", f"<h1>{e(ctx['title'])}</h1>"]
    parts += model_section(ctx) + training_section(ctx) + video_section(ctx) + head_section(ctx) + bench_sections(ctx)
    parts.append("<h2>Synthesis speed</h2><p>Measured on every run, so not on this page (its bytes are the same on "
                 "every run and machine, and DVC's cache can trust them): the last run's thread time per frame and "
                 "phase is in <code>logs/synthesize.timing.json</code> and <code>logs/composite.timing.json</code>; "
                 "<code>bench/synthesize.py</code> measures it properly.</p>")
    parts.append(f"<h2>Parameters</h2><pre id=\"params\">{e(ctx.get('params_text', ''))}</pre>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def model_section(ctx: dict) -> list[str]:
    """The model families' table: validation mouth error of each, with the baselines."""
    parts = ["<h2>Audio → mouth shape: model families</h2>"]
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
    return parts


def training_section(ctx: dict) -> list[str]:
    """Loss curves, the delay sweep, and the Voice Puppetry and Karras models' own figures."""
    e = html.escape
    parts = ["<h2>Training</h2>"]
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
    return parts


def video_section(ctx: dict) -> list[str]:
    """The synthesized video against the original (Video J): the evaluate table and the shown clips."""
    e = html.escape
    parts = ["<h2>Audio → video: the synthesized video against the original (Video J)</h2>"]
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
    return parts


def head_section(ctx: dict) -> list[str]:
    """With the render_mesh stage's glTF head (``ctx['head_glb']``, ``ctx['head_audio']``): its three.js viewer."""
    if not ctx.get("head_glb"):
        return []
    return ["<h2>The 3D head (Karras et al.)</h2><p>The speaker's textured head mesh driven by the model's predicted "
            "face points for the synthesized audio, as exported (<code>head.glb</code>, glTF 2.0). Play the audio to "
            "animate it; drag to orbit, scroll to zoom.</p>",
            gltf_viewer.viewer_html("head", ctx.get("head_audio"), rel="head/")]


def bench_sections(ctx: dict) -> list[str]:
    """With ``report.benches``: the DVC path beside the ``lipsynth speak`` path, and other people's voices."""
    parts = []
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
    return parts


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
               params_text=shown_params(params), **benches(params.report.benches, root))
    glb = root / params.render_mesh.export / "head.glb"
    if glb.is_file():
        ctx.update(head_glb=glb, head_audio="head.wav" if glb.with_suffix(".wav").is_file() else None)
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
        if ctx.get("head_glb"):
            gltf_viewer.write_viewer_assets(tmp / "head", ctx["head_glb"], rel="head/")
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
