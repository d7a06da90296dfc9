"""``lipsynth emotions`` — the emotion vectors a Karras model offers (paper 001 §5.1).

    lipsynth emotions --model models/karras [--json]

Training learns one emotion vector per training frame (the emotion database); ``train_karras``
mines it: vectors that close the mouth on closed-mouth validation windows and open it on open
ones, then do not subdue or jitter the motion over validation clips, clustered; each cluster's
most accurate member is a candidate. Candidates are listed by validation mouth error: 0 is the
default. Use one with ``--emotion K`` (predict-mouth, speak, render-mesh) or interpolate two with
``--emotion K1:K2:t``.

Columns: the candidate's index; cluster size (database vectors it stands for); the training frame
it was learned on; the videos its cluster comes from; response (predicted open − closed opening on
the probes, relative to the tracked one); opening std and jitter relative to the tracked mouth on
validation clips; validation mouth error (px, mean over 42 lower-face points).
"""
from __future__ import annotations

import argparse
import json

from pipeline.models.model_folder import ModelError, load_karras
from pipeline.io.runner import run_main, setup_logging


def table(info: list[dict]) -> str:
    head = f"{'K':>3} {'cluster':>7}  {'learned on':<22} {'response':>8} {'std':>5} {'jitter':>6} {'err px':>6}  videos"
    rows = [head]
    for r in info:
        vids = ", ".join(f"{k}×{v}" for k, v in list(r.get("videos", {}).items())[:3])
        rows.append(f"{r['index']:>3} {r.get('cluster_size', 0):>7}  {r['video'] + ':' + str(r['frame']):<22} "
                    f"{r.get('response', float('nan')):>8.2f} {r.get('opening_std_ratio', float('nan')):>5.2f} "
                    f"{r.get('jitter_ratio', float('nan')):>6.2f} {r.get('val_error_px', float('nan')):>6.3f}  {vids}"
                    + ("   ← default" if r["index"] == 0 else ""))
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth emotions", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="models/karras", help="a Karras model folder (default: models/karras)")
    ap.add_argument("--json", action="store_true", help="print the candidates as JSON")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)

    def go():
        model = load_karras(a.model)
        info = model["config"].get("emotion_info")
        if not info:
            raise ModelError(f"{a.model}: the model folder lists no mined emotions")
        if a.json:
            print(json.dumps(info, indent=2))
        else:
            print(f"{a.model}: {len(info)} emotion candidates of {len(model['emotion_database'])} learned vectors\n")
            print(table(info))
    return run_main(go)


if __name__ == "__main__":
    raise SystemExit(main())
