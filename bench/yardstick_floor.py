"""How low can the lip-sync yardstick go? Its floor, step by step along the `speak` path (issue 9).

`../shared/tools/lipsync_yardstick.py` runs dlib on every frame of the output O and of the
original C. Any O that is not C byte for byte moves dlib's detector box and landmarks a little,
so the mouth error / static error ratio has a floor above zero. This bench measures it on the
given clips (each its own audio and target, `--no-retime`), one row per step:

  reencode_lossless  C decoded and written again (H.264 lossless): only rounding changes
  reencode_crfN      the same at `composite.crf` N (what every output goes through)
  own_texture        `speak` with the target's tracked lips and one candidate (its own frame):
                     frontalize → texture → render-back → blend, no synthesis
  oracle             `speak` with the tracked lips (n candidates, weighted median, teeth proxy)
  model              `speak` with the model's prediction (what users run)

    python bench/yardstick_floor.py --model runs/grid_s1/models/lstm_vtlp CLIP.mp4 ... \
        [--crf 18] [--rows reencode_lossless,own_texture,...] [--out bench/results/yardstick_floor.json]

Prints err_ratio / corr / within-one-frame per row and writes the JSON and a bar plot beside it.
`python bench/yardstick_floor.py reencode SRC OUT --crf N` is the re-encoding step on its own.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
YARDSTICK = ROOT.parent / "shared" / "tools" / "lipsync_yardstick.py"
ROWS = ["reencode_lossless", "reencode_crf", "own_texture", "oracle", "model"]


def reencode(src: str, out: str, crf: int) -> None:
    """Decode ``src`` and write its frames and audio again as H.264 (+ AAC) at ``crf``."""
    from pipeline.io import media
    audio, _ = media.read_audio(src, 48000)
    media.write_video(out, (frame for _, frame in media.iter_frames(src)), media.probe(src).fps, audio, 48000, crf)


def params_with(overrides: dict, path: Path) -> str:
    """Write params.yaml with ``{section: {key: value}}`` overrides to ``path``; returns it."""
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    for section, values in overrides.items():
        tree[section].update(values)
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return str(path)


def commands(model: str, crf: int, cache: str, folder: Path) -> dict:
    py = sys.executable
    oracle = f"{py} bench/speak_oracle.py --model {model} --audio {{audio}} --target {{target}} --out {{out}} --cache {cache}"
    speak = (f"{py} -m lipsynth.cli speak --model {model} --audio {{audio}} --target {{target}} --out {{out}} "
             f"--no-retime --cache {cache}")
    at_crf = params_with({"composite": {"crf": crf}}, folder / "params_crf.yaml")
    one_candidate = params_with({"composite": {"crf": crf}, "synthesize": {"n": 1}}, folder / "params_own.yaml")
    return {
        "reencode_lossless": f"{py} bench/yardstick_floor.py reencode {{target}} {{out}} --crf 0",
        "reencode_crf": f"{py} bench/yardstick_floor.py reencode {{target}} {{out}} --crf {crf}",
        "own_texture": f"{oracle} --params {one_candidate}",
        "oracle": f"{oracle} --params {at_crf}",
        "model": f"{speak} --params {at_crf}",
    }


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "reencode":
        ap = argparse.ArgumentParser(prog="yardstick_floor.py reencode")
        ap.add_argument("cmd")
        ap.add_argument("src")
        ap.add_argument("out")
        ap.add_argument("--crf", type=int, default=18)
        a = ap.parse_args()
        reencode(a.src, a.out, a.crf)
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("clips", nargs="+")
    ap.add_argument("--model", default="runs/grid_s1/models/lstm")
    ap.add_argument("--crf", type=int, default=18, help="composite.crf of the speak rows and the re-encoding")
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--cache", default="/tmp/speak_cache")
    ap.add_argument("--out", default="bench/results/yardstick_floor.json")
    a = ap.parse_args()
    if not YARDSTICK.is_file():
        raise SystemExit(f"{YARDSTICK}: the yardstick is not there (../shared/tools beside the project)")
    rows = [r for r in a.rows.split(",") if r]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        raise SystemExit(f"--rows: unknown {', '.join(unknown)} (choose from {', '.join(ROWS)})")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        cmds = commands(a.model, a.crf, a.cache, Path(tmp))
        for row in rows:
            js = Path(tmp) / f"{row}.json"
            r = subprocess.run([sys.executable, str(YARDSTICK), "--make", cmds[row], "--json", str(js), *a.clips],
                               cwd=ROOT, capture_output=True, text=True)
            if not js.is_file():
                raise SystemExit(f"{row}: the yardstick wrote nothing (rc {r.returncode}): {r.stderr.strip()[-500:]}")
            res = json.loads(js.read_text())
            results[row] = res
            s = res["summary"]
            print(f"{row:18s} ratio {s.get('err_ratio', float('nan')):.3f}  corr {s.get('corr', float('nan')):.3f}  "
                  f"≤1 frame {100 * s.get('within_1_frame', 0):.0f}%  sharp {s.get('sharp', float('nan')):.2f}  "
                  f"ok {s['ok']}/{s['clips']}", flush=True)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(model=a.model, crf=a.crf, clips=[Path(c).name for c in a.clips], rows=results),
                              indent=1))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.2))
    names = [r for r in rows if "err_ratio" in results[r]["summary"]]
    ax.barh(names[::-1], [results[r]["summary"]["err_ratio"] for r in names[::-1]], color="#4c72b0")
    ax.axvline(0.70, color="crimson", ls="--", label="issue 9 goal 0.70")
    ax.set_xlabel("mouth error / static error (yardstick, median over clips)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=120)
    print(f"wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
