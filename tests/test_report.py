"""The report page (stages/report) and the evaluate stage's pure pieces; a headless-Chromium check.

Fast: the HTML builder on small fake metrics (table rows, one inline <svg> per plot, relative
video src), deterministic SVG, the clip choice, the evaluate summaries, ``lipsynth report``.
Slow: headless Chromium (DevTools protocol) loads a page from disk — no console errors, every
<video> reaches readyState ≥ 2 with the right duration, every plot rendered — and saves a
full-page screenshot to the test's temp dir.
"""
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.params import Params, as_dict, parse
from stages.evaluate import evaluate
from stages.report import report
from tests.conftest import ROOT
from tests.helpers.browser import assert_page_renders, check_in_browser

TRAIN = {"model": "lstm", "delay_steps": 20,
         "val": {"mouth_error_px": 0.94, "mouth_error_iod_pct": 1.31, "av_within_one_frame": 1.0,
                 "median_opening_corr": 0.93, "n_clips": 1},
         "baseline_mean_shape": {"mouth_error_px": 2.0, "mouth_error_iod_pct": 2.77, "av_within_one_frame": math.nan,
                                 "median_opening_corr": math.nan, "n_clips": 0},
         "baseline_lstm_delay0": {"mouth_error_px": 1.56, "mouth_error_iod_pct": 2.16, "av_within_one_frame": 1.0,
                                  "median_opening_corr": 0.6, "n_clips": 1},
         "ratio_to_mean_shape": 0.47}


def clip(name, err, frames=50, fps=25.0):
    return {"clip": name, "frames": frames, "fps": fps, "mouth_error_px": err, "mouth_error_iod_pct": err,
            "static_mouth_error_px": 2.8, "static_mouth_error_iod_pct": 3.4, "opening_corr": 0.9,
            "opening_best_lag": 0, "mouth_mad": 4.0, "sharpness_ratio": 0.7, "flicker_ratio": 0.96,
            "fallen_back": 0, "video": f"{name}.mp4", "diagnostic_video": f"{name}.diagnostic.mp4",
            "opening_csv": f"{name}.opening.csv"}


def opening_rows(n=50, fps=25.0):
    return [{"frame": str(i), "time_s": f"{i / fps:.4f}", "output_px": f"{3 + np.sin(i / 4):.3f}",
             "original_px": f"{3 + np.sin(i / 4 + 0.2):.3f}"} for i in range(n)]


def fake_ctx(n_clips=1):
    clips = [clip(f"speaker_{i:02d}", 1.0 + i) for i in range(n_clips)]
    ev = {"setting": "Video J", "exclude_target_from_pool": True, "clips": n_clips,
          "median": evaluate.summarise(clips), "per_clip": clips}
    loss = [{"model": "lstm", "step": str(10 * e), "epoch": str(e), "train_loss": str(100 / e), "val_loss": str(120 / e)}
            for e in range(1, 20)]
    sweep = [{"delay_ms": str(d), "val_loss": str(50 - d / 10), "val_mouth_error_px": "1.2"} for d in (0, 50, 100, 200, 400)]
    shown = [(label, c, opening_rows(), f"videos/{c['diagnostic_video']}", 2.0) for label, c in report.shown_clips(clips)]
    return dict(title="t <&>", train=TRAIN, loss_rows=loss, sweep_rows=sweep, paper_delay_ms=200.0, evaluate=ev,
                clips=shown, timings={"synthesize": {"prediction": 3.7}, "composite": None, "evaluate": None},
                params_text="a: 1  # <b>\n", commit="abc123", date="2026-01-01 00:00 UTC")


# ---------------------------------------------------------------- fast

def test_model_table_has_the_model_and_its_baselines_with_ratios_to_the_mean_shape():
    rows = report.model_rows(TRAIN)
    assert [r[0] for r in rows] == ["lstm (delay 200 ms)", "baseline: lstm, delay 0", "baseline: mean shape"]
    assert rows[0][1:6] == ["0.94", "1.31", "0.47", "0.930", "100%"]
    assert rows[1][3] == "0.78" and rows[2][3] == "1.00" and rows[2][4] == "—"
    assert report.model_rows(None) == []


BRAND = {"states_initial": 26, "face_dims": 12, "face_variance_kept": 0.9, "features": "paper", "rate": 25.0,
         "training_frames": 1000,
         "entropic": {"states": 21, "transitions": 300, "transition_perplexity": 2.5, "entropy_rate_nats": 0.12,
                      "eq7": {"state_sequence": {"train": 0.18, "test": 0.24}, "voice": {"train": 0.25, "test": 0.29}},
                      "val": {"mouth_error_px": 1.5, "mouth_error_iod_pct": 2.1, "median_opening_corr": 0.73,
                              "av_within_one_frame": 1.0, "n_clips": 1}},
         "ml": {"states": 21, "transitions": 420, "transition_perplexity": 2.7, "entropy_rate_nats": 0.15,
                "eq7": {"state_sequence": {"train": 0.17, "test": 0.23}, "voice": {"train": 0.24, "test": 0.28}},
                "val": {"mouth_error_px": 1.6, "mouth_error_iod_pct": 2.2, "median_opening_corr": 0.7,
                        "av_within_one_frame": 1.0, "n_clips": 1}}}


def test_brand_rows_sit_beside_the_lstm_with_the_papers_figures():
    rows = report.brand_rows(BRAND, 2.0)
    assert [r[0] for r in rows] == ["Voice Puppetry (entropic HMM)", "baseline: maximum-likelihood HMM"]
    assert rows[0][1:4] == ["1.50", "2.10", "0.75"]
    paper = report.brand_paper_rows(BRAND)
    assert "0.180 / 0.240 (paper 0.1255 / 0.1698)" == paper[0][1] and "(paper 0.875)" in paper[1][3]
    page = report.build_html(dict(fake_ctx(1), brand=BRAND, brand_rows=[
        {"model": m, "iteration": str(i), "log_posterior": str(-30 + i)} for m in ("entropic", "ml") for i in range(1, 5)]))
    assert page.count("<svg") == 4 and "Voice Puppetry (paper 002" in page
    assert report.brand_rows(None, 2.0) == [] and report.brand_paper_rows(None) == []


def test_page_has_tables_one_svg_per_plot_relative_videos_and_escapes_text():
    page = report.build_html(fake_ctx(1))
    assert page.count("<svg") == 3                    # loss, sweep, one opening plot
    assert page.count("<video") == 1 and 'src="videos/speaker_00.diagnostic.mp4"' in page
    assert 'data-duration="2.000"' in page
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page) and "<link" not in page   # no network
    assert "<script" not in page
    assert "t &lt;&amp;&gt;" in page and "# &lt;b&gt;" in page
    assert page.count("<tr>") == 1 + 3 + 1 + 2           # model table, evaluate (clip + median); no timing table (was 2 rows)
    assert "paper: 200 ms" in page


def test_other_voices_and_the_speak_path_are_shown_per_person_and_path(tmp_path):
    group = lambda lag0, best: {"n": 2, "median_corr_lag0": lag0, "median_corr_best": best, "within_one_frame": 0.5,
                                "median_source_offset": -2.0, "median_corr_source_lag": best - 0.01}
    cross = {"models": {"a": {"label": "lstm (mfcc, corpus)", "groups": {"obama": group(0.1, 0.3), "lieu": group(0.2, 0.4)},
                              "core_clips": 4, "median_corr_lag0": 0.15, "median_corr_best": 0.35, "within_one_frame": 0.25,
                              "median_corr_source_lag": 0.3, "in_domain": {"mouth_error_iod_pct": 1.15}},
                        "b": {"label": "base (whisper, corpus)", "groups": {"obama": group(0.5, 0.7)}, "core_clips": 4,
                              "median_corr_lag0": 0.5, "median_corr_best": 0.7, "within_one_frame": 0.75,
                              "median_corr_source_lag": 0.6}}}
    quality = {"clips": 3, "median": {"mouth_error_px": 0.8, "error_ratio": 0.61, "opening_corr": 0.906,
                                      "within_1_frame": 1.0, "sharpness_ratio": 0.75, "flicker_ratio": 0.93}}
    (tmp_path / "cross_speaker.json").write_text(json.dumps(cross))
    (tmp_path / "synthesis_quality_speak.json").write_text(json.dumps(quality))
    ctx = dict(fake_ctx(1), **report.benches(str(tmp_path), Path(".")))
    page = report.build_html(ctx)
    assert page.count("<svg") == 4                                       # + the per-person plot
    rows = re.findall(r"<tr>(.*?)</tr>", page.split("Other voices")[1].split("</table>")[0])
    assert len(rows) == 1 + 3 + 2                                       # header; 2 people + all, 1 person + all
    assert "<td>lieu</td><td>2</td><td>0.20</td><td>0.40</td><td>50%</td><td>-2</td><td>0.39</td>" in rows[2]
    assert "in-domain 1.150 % IOD" in rows[3]
    speak = page.split("<code>lipsynth speak</code> path")[1].split("</table>")[0]
    assert speak.count("<tr>") == 1 + 1 and "<td>lipsynth speak (clip files)</td><td>3</td><td>0.800</td><td>0.61</td>" \
        "<td>0.906</td><td>100%</td>" in speak                       # the DVC-path files are absent: no rows
    assert report.benches(None, Path(".")) == {}
    assert "Other voices" not in report.build_html(fake_ctx(1))


def test_page_does_not_depend_on_when_where_or_how_fast_it_was_made():
    """The same inputs give the same bytes whatever the date, the commit or the last run's timings: DVC's hash
    of the report reproduces on a fresh clone."""
    a, b = fake_ctx(2), fake_ctx(2)
    b.update(date="2030-12-31 23:59 UTC", commit="def456", timings={"synthesize": {"prediction": 99.0}})
    page = report.build_html(a)
    assert page == report.build_html(b)
    assert "2026-01-01" not in page and "abc123" not in page and "logs/synthesize.timing.json" in page


def test_more_than_three_clips_show_worst_median_and_best():
    clips = [clip(f"c{i}", e) for i, e in enumerate([3.0, 1.0, 2.0, 5.0, 4.0])]
    shown = report.shown_clips(clips)
    assert [(label, c["clip"]) for label, c in shown] == [("worst", "c3"), ("median", "c0"), ("best", "c1")]
    assert len(report.shown_clips(clips[:2])) == 2


def test_evaluate_picks_spread_validation_clips_and_summarises():
    videos = [{"name": f"v{i}", "split": "val" if i % 2 else "train", "n_frames": 10} for i in range(12)]
    assert [v["name"] for v in evaluate.pick_clips(videos, 3)] == ["v1", "v3", "v9"]   # by name: v1 v11 v3 v5 v7 v9
    assert len(evaluate.pick_clips(videos, 3)) == 3 and evaluate.pick_clips(videos[:1], 3) == []
    med = evaluate.summarise([clip("a", 1.0), clip("b", 2.0), dict(clip("c", 3.0), opening_best_lag=4)])
    assert med["mouth_error_px"] == 2.0 and med["error_ratio"] == pytest.approx(2.0 / 2.8)
    assert med["within_1_frame"] == pytest.approx(2 / 3)
    assert evaluate.rounded({"x": [float("nan"), 1.23456789]}) == {"x": [None, 1.234568]}


def test_evaluate_clip_params_are_video_j_and_a_valid_params_file(tmp_path):
    tree = evaluate.clip_params(Params(), {"name": "speaker_03", "path": "data/x/speaker_03.mp4"}, tmp_path, True, True)
    p = parse(yaml.safe_load(yaml.safe_dump(tree)))
    assert p.synthesize.retime is False and p.synthesize.exclude_target_from_pool is True
    assert p.synthesize.audio == "data/x/speaker_03.mp4" and p.synthesize.target == "speaker_03"
    assert p.synthesize.out.startswith(str(tmp_path)) and p.composite.out_dir.startswith(str(tmp_path))


def write_fixture_project(tmp_path, video_seconds=2.0, fps=25.0):
    """Fake metrics/plots/evaluate outputs in tmp_path, a real 2 s H.264 clip; returns the params file."""
    from pipeline.io import media
    tree = as_dict(Params())
    tree["train"].update(metrics=str(tmp_path / "train.json"), plots=str(tmp_path / "loss.csv"))
    tree["brand"].update(metrics=str(tmp_path / "brand.json"), plots=str(tmp_path / "brand.csv"))
    tree["karras"].update(metrics=str(tmp_path / "karras.json"), plots=str(tmp_path / "karras.csv"))   # absent: no row
    tree["delay_sweep"]["plots"] = str(tmp_path / "sweep.csv")
    tree["evaluate"].update(out=str(tmp_path / "evaluate"), metrics=str(tmp_path / "evaluate.json"))
    tree["report"]["out"] = str(tmp_path / "report")
    tree["render_mesh"]["export"] = str(tmp_path / "head")                   # absent: no 3D viewer
    ctx = fake_ctx(1)
    (tmp_path / "train.json").write_text(json.dumps(TRAIN))
    for name, rows in (("loss.csv", ctx["loss_rows"]), ("sweep.csv", ctx["sweep_rows"])):
        (tmp_path / name).write_text(",".join(rows[0]) + "\n" + "".join(",".join(r.values()) + "\n" for r in rows))
    n = int(video_seconds * fps)
    c = clip("speaker_00", 1.0, frames=n, fps=fps)
    (tmp_path / "evaluate.json").write_text(json.dumps(dict(ctx["evaluate"], per_clip=[c])))
    (tmp_path / "evaluate").mkdir()
    rows = opening_rows(n, fps)
    (tmp_path / "evaluate" / c["opening_csv"]).write_text(
        "frame,time_s,output_px,original_px\n" + "".join(",".join(r.values()) + "\n" for r in rows))
    yy, xx = np.mgrid[0:96, 0:160]
    frames = [np.stack([(xx + 4 * i) % 256, yy * 2, np.full_like(xx, 128)], -1).astype(np.uint8) for i in range(n)]
    media.write_video(tmp_path / "evaluate" / c["diagnostic_video"], frames, fps)
    pfile = tmp_path / "params.yaml"
    pfile.write_text(yaml.safe_dump(tree, sort_keys=False, allow_unicode=True))
    return pfile, tree


def test_lipsynth_report_writes_the_folder_and_prints_the_page_path(tmp_path):
    pfile, tree = write_fixture_project(tmp_path)
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "report", "--params", str(pfile)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    page = Path(tree["report"]["out"]) / "index.html"
    assert r.stdout.strip().splitlines()[-1] == str(page)
    assert (page.parent / "videos" / "speaker_00.diagnostic.mp4").is_file()
    text = page.read_text()
    assert text.count("<svg") == 3 and 'src="videos/speaker_00.diagnostic.mp4"' in text
    assert "lipsynth — synthetic speaker" in text and yaml.safe_load(pfile.read_text())["report"]["out"] in text


# ---------------------------------------------------------------- slow: a real browser

@pytest.mark.slow
def test_the_report_renders_in_headless_chromium(tmp_path):
    """A page from fixture data (a real 2 s H.264 clip): plays, plots render, no console errors."""
    pfile, tree = write_fixture_project(tmp_path)
    page = report.write_report(report.load_params(pfile), pfile)
    state = check_in_browser(page, tmp_path / "screenshot.png")
    print(f"screenshot: {tmp_path / 'screenshot.png'}")
    assert_page_renders(state, n_videos=1, n_svgs=3)
    assert state["videos"][0]["duration"] == pytest.approx(2.0, abs=0.1)
    assert (tmp_path / "screenshot.png").stat().st_size > 10_000


def test_the_committed_grid_page_plays_its_videos_in_headless_chromium(tmp_path):
    """reports/grid_s1/ is committed (docs/report.md links it): every player on it finds its clip and plays it."""
    page = ROOT / "reports" / "grid_s1" / "index.html"
    text = page.read_text()
    sources = re.findall(r'<video[^>]*src="([^"]+)"', text) + re.findall(r'<source[^>]*src="([^"]+)"', text)
    assert len(sources) == text.count("<video") >= 1, "the GRID page shows no video"
    missing = [s for s in sources if not (page.parent / s).is_file()]
    assert not missing, f"{page} names videos that are not committed: {missing}"
    state = check_in_browser(page, tmp_path / "screenshot.png")
    assert_page_renders(state, n_videos=text.count("<video"), n_svgs=text.count("<svg"))
