"""Where in Whisper tiny.en does articulation live? The read-out ceiling of each encoder layer (issue 61, item 2).

    python bench/layer_ceiling.py [--people runs/diagnosis] [--corpus runs/natural_corpus] [--grid STORES|none]
        [--encoder tiny.en|base] [--track] [--lam 0.3]

Every layer of the encoder is reachable through the torch port (``pipeline.audio.whisper_layers``: the
convolution stem = layer 0, the four blocks = 1–4, the final layer norm = 5, which is what the shipped
``whisper`` front end reads). For each layer, a ridge regression from context-stacked states (the 100-Hz
states at each video frame and ±300 ms around it at 60-ms steps: 11 × 384 inputs, as
``bench/readout_ceiling.py``) to the per-clip standardised inner-lip opening (landmarks 62–66 over the
inter-ocular distance) is trained leave-one-person-out over every person at hand and correlated with the
held-out person's tracked opening, at lag 0 and at the best lag within ±5 frames:

    strangers   the nine strangers (``bench/strangers.py``'s landmark cache), each one person (with the longer
                footage of the strangers that ``bench/person_diagnosis.py`` personalized: the same person)
    people      the personalized people (``bench/person_diagnosis.py``'s stores, ``NAME/w/store``): Obama,
                GRID s4, Lieu, Macron, the HDTF two and the long strangers' own footage
    corpus      the natural-speech corpus' people (``bench/natural_corpus.py``'s clips; ``--track`` tracks
                them once, as ``speak`` tracks a target), when ``--corpus`` holds one; its Obama and GRID s4
                clips join those people's own group

Two mixes of layers are gauged the same way: ``mix_all`` (every layer, each cut to its first 64 principal
components; the projections are fitted on every clip's audio, no opening involved) and ``mix_best2`` (the two
best single layers, all 384 dimensions each). The ridge is solved from per-person sufficient statistics (Σx, Σxxᵀ, Σxy, Σy, n), so a
leave-one-out fold subtracts one person's; inputs are standardised with the fold's own mean and SD.

Two protocols: the *ceiling* (every person is held out in turn, the read-out trained on all the others,
GRID s1 left out so natural speech is not drowned), and *transfer* (trained once on the footage that may
train shipped weights — GRID s1's third in ``--grid``, the weekly addresses of Obama, AOC and Hill, the
corpus' public-domain and CC clips — and scored on everyone else: what a shipped base can reach).

``--encoder base`` gauges OpenAI's Whisper base the same way (``pipeline.audio.whisper_layers.ENCODERS``: two
pinned pip packages of the ``encoders`` extra); ``--grid none`` leaves GRID s1 out (its encoding costs the most).

Writes ``results/layer_ceiling.json`` and the page ``docs/layer_ceiling.md`` with its plot (``_base`` for base).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from bench.bench_results import publish, stamp
from bench.readout_ceiling import clips_of
from pipeline.audio.whisper_encoder import to_frame_axis
from pipeline.audio.whisper_layers import ENCODERS, layer_states
from pipeline.measures.lipsync_measures import best_lag
from pipeline.models.mouth_prediction import load_audio

ROOT = Path(__file__).resolve().parents[1]
OFFS = np.arange(-30, 31, 6)                 # 100-Hz context offsets (±300 ms)
CACHE = ROOT / "runs" / "layer_ceiling"
PEOPLE = ("obama", "grid_s4", "lieu", "macron", "hdtf_aoc", "hdtf_hill", "sky_drive2", "latsync_demo2",
          "latsync_demo3")
SHIPPABLE_PEOPLE = ("obama", "hdtf_aoc", "hdtf_hill")      # US federal government works (weekly addresses)
SHIPPABLE_CLASSES = ("public_domain", "cc0", "cc_by")
SAME_PERSON = {"barack_obama": "obama", "grid_s4": "grid_s4"}     # corpus people who are people above


def layer_names(n_layers: int) -> list[str]:
    """stem, block1 … blockN, final for an encoder with ``n_layers`` reachable states."""
    return ["stem"] + [f"block{i}" for i in range(1, n_layers - 1)] + ["final"]


def clip_layers(path: str, encoder: str = "tiny.en") -> np.ndarray:
    """(layers, T100, width) float16 states of the clip's audio on the 100-Hz axis (cached per file and encoder)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    suffix = "" if encoder == "tiny.en" else f"__{encoder}"
    f = CACHE / f"{Path(path).parent.name}__{Path(path).stem}{suffix}.npy"
    if not f.exists():
        x = load_audio(path)
        states = layer_states(x, name=encoder)
        n = 1 + len(x) // 160
        np.save(f, np.stack([to_frame_axis(s, n) for s in states]).astype(np.float16))
    return np.load(f)


def design(states: np.ndarray, fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, 11 · D) the 100-Hz rows ``states`` (T100, D) at each video frame's time and ±OFFS around it."""
    idx = np.round(np.arange(n_frames) / fps * 100).astype(int)
    return np.concatenate([states[np.clip(idx + o, 0, len(states) - 1)] for o in OFFS], 1).astype(np.float64)


def standardised_truth(truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = np.isfinite(truth)
    return m, (truth[m] - truth[m].mean()) / (truth[m].std() + 1e-9)


def stats(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict:
    """Sufficient statistics (n, Σx, Σxxᵀ, Σxy) of one person's clips' valid rows for a ridge solve."""
    out = None
    for x, y, m in rows:
        xm = x[m]
        part = dict(n=len(xm), sx=xm.sum(0), sxx=xm.T @ xm, sxy=xm.T @ y)
        out = part if out is None else {k: out[k] + part[k] for k in out}
    return out


def combined(parts: list[dict], minus: dict | None = None) -> dict:
    """The sum of several people's statistics, less ``minus``'s (a leave-one-out fold)."""
    total = {k: sum(p[k] for p in parts) for k in parts[0]}
    return {k: total[k] - minus[k] for k in total} if minus else total


def solve(st: dict, lam: float) -> tuple:
    """Ridge on standardised inputs (λ · n on the diagonal) from summed statistics: (mu, sd, w)."""
    n = st["n"]
    mu = st["sx"] / n
    cov = st["sxx"] / n - np.outer(mu, mu)
    sd = np.sqrt(np.maximum(np.diag(cov), 0)) + 1e-6
    a = cov / np.outer(sd, sd) + lam * np.eye(len(mu))
    b = (st["sxy"] / n) / sd                                  # targets are zero-mean per clip
    return mu, sd, np.linalg.solve(a, b)


def scores(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Correlation at lag 0 and at the best lag within ±5 frames of a prediction with a tracked opening."""
    m = np.isfinite(truth)
    lag0 = float(np.corrcoef(pred[m], truth[m])[0, 1])
    lag = best_lag(truth, pred)
    n = len(truth)
    x, y = truth[max(lag, 0):n + min(lag, 0)], pred[max(-lag, 0):n + min(-lag, 0)]
    g = np.isfinite(x)
    return lag0, float(np.corrcoef(x[g], y[g])[0, 1])


def load_people(a) -> tuple[dict[str, list[dict]], set[str]]:
    """Person → clips (name, path, fps, truth) of every set at hand, and the people whose footage may train
    shipped weights (GRID s1, the weekly addresses, the corpus' public-domain and CC clips)."""
    groups: dict[str, list[dict]] = {}
    shippable = {f"person:{p}" for p in SHIPPABLE_PEOPLE}
    if a.grid and str(a.grid) != "none" and (a.grid / "landmarks.zarr").exists():
        grid = clips_of(a.grid / "landmarks.zarr")
        for c in grid:
            c["path"] = str(a.grid_videos / Path(c["path"]).name)
        groups["grid_s1"] = grid
        shippable.add("grid_s1")
    for mp4 in sorted(a.strangers.glob("*.mp4")):
        found = sorted(a.cache.glob(f"{mp4.stem}-*/landmarks.zarr"))
        if found:
            c = clips_of(found[-1])[0]
            c["path"] = str(mp4)
            groups[f"stranger:{mp4.stem}"] = [c]
    for p in PEOPLE:
        lm = a.people / p / "w" / "store" / "landmarks.zarr"
        if lm.exists():                # a stranger's longer footage is the same person: one group, held out together
            key = f"stranger:{p}" if f"stranger:{p}" in groups else f"person:{p}"
            groups.setdefault(key, []).extend(clips_of(lm))
    corpus = a.corpus / "corpus.json"
    if corpus.exists():
        for clip in json.loads(corpus.read_text())["clips"]:
            found = sorted((a.corpus / "cache").glob(f"{clip['clip']}-*/landmarks.zarr"))
            if clip["kept"] and found:
                cs = clips_of(found[-1])
                for c in cs:
                    c["path"] = str(a.corpus / "clips" / f"{clip['clip']}.mp4")
                person = clip["person"]
                key = f"person:{SAME_PERSON[person]}" if person in SAME_PERSON else f"corpus:{person}"
                groups.setdefault(key, []).extend(cs)
                if clip["licence_class"] in SHIPPABLE_CLASSES and key.startswith("corpus:"):
                    shippable.add(key)
    return groups, shippable


def track_corpus(corpus: Path) -> None:
    """dlib landmarks of every kept corpus clip (``lipsynth speak``'s target preprocessing, cached in ``corpus/cache``)."""
    from lipsynth.target import landmarked_target
    from pipeline.errors import LipsynthError
    from pipeline.params import load_params
    params = load_params(ROOT / "params.yaml")
    for clip in json.loads((corpus / "corpus.json").read_text())["clips"]:
        if clip["kept"]:
            try:
                landmarked_target(corpus / "clips" / f"{clip['clip']}.mp4", params, corpus / "cache")
            except LipsynthError as exc:
                print(f"{clip['clip']}: not tracked: {exc}", flush=True)


def person_rows(groups: dict, build) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Person → [(design rows, standardised truth, mask)] with ``build(clip) -> (T, D)`` inputs."""
    out = {}
    for g, clips in groups.items():
        rows = []
        for c in clips:
            x = build(c)
            m, y = standardised_truth(c["truth"][:len(x)])
            rows.append((x, y, m))
        out[g] = rows
    return out


def leave_one_out(rows: dict, lam: float) -> dict[str, dict]:
    """Each person's lag-0 and best-lag correlation (medians over their clips) from a ridge fitted on the others."""
    total = None
    for r in rows.values():                   # one person's statistics at a time (each is D² floats)
        part = stats(r)
        total = part if total is None else combined([total, part])
    out = {}
    for g, r in rows.items():
        mu, sd, w = solve(combined([total], stats(r)), lam)
        s = [scores(((x - mu) / sd) @ w, truth_of(y, m)) for x, y, m in r]
        out[g] = dict(lag0=float(np.median([a for a, _ in s])), best=float(np.median([b for _, b in s])))
    return out


def transfer(rows: dict, train: set[str], lam: float) -> dict[str, dict]:
    """Each person outside ``train``: lag-0 and best-lag correlation from one ridge fitted on ``train``'s people."""
    total = None
    for g in train:
        part = stats(rows[g])
        total = part if total is None else combined([total, part])
    mu, sd, w = solve(total, lam)
    out = {}
    for g, r in rows.items():
        if g not in train:
            s = [scores(((x - mu) / sd) @ w, truth_of(y, m)) for x, y, m in r]
            out[g] = dict(lag0=float(np.median([a for a, _ in s])), best=float(np.median([b for _, b in s])))
    return out


def truth_of(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """(T,) standardised truth with NaN where untracked."""
    t = np.full(len(m), np.nan)
    t[m] = y
    return t


def pca_basis(states: list[np.ndarray], k: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and the first ``k`` principal directions (D, k) of stacked rows (T, D)."""
    x = np.concatenate(states).astype(np.float64)
    mu = x.mean(0)
    _, vec = np.linalg.eigh(np.cov(x - mu, rowvar=False))
    return mu, vec[:, ::-1][:, :k]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--people", type=Path, default=ROOT / "runs" / "diagnosis", help="NAME/w/store of each person")
    ap.add_argument("--strangers", type=Path, default=ROOT.parent / "shared" / "data" / "strangers")
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "strangers" / "cache", help="the strangers' speak cache")
    ap.add_argument("--corpus", type=Path, default=ROOT / "runs" / "natural_corpus", help="bench/natural_corpus.py's output")
    ap.add_argument("--lam", type=float, default=0.3, help="ridge strength (× frames, on standardised inputs)")
    ap.add_argument("--grid", type=Path, default=ROOT / "runs" / "grid3_L3" / "store",
                    help="GRID s1 stores (bench/shipped_base.py --every 3's); trained on in the shippable protocol")
    ap.add_argument("--grid-videos", type=Path, default=ROOT.parent / "shared" / "data" / "grid_s1" / "video")
    ap.add_argument("--encoder", default="tiny.en", choices=["tiny.en", *ENCODERS],
                    help="which Whisper: tiny.en (shipped) or base (the encoders extra; page layer_ceiling_base)")
    ap.add_argument("--track", action="store_true", help="first track the corpus clips' landmarks (once)")
    a = ap.parse_args()
    if a.track:
        track_corpus(a.corpus)
    groups, shippable = load_people(a)
    clips = [c for cs in groups.values() for c in cs]
    print(f"{len(groups)} people ({len(shippable)} shippable), {len(clips)} clips, "
          f"{sum(len(c['truth']) for c in clips)} frames", flush=True)
    layers = {c["path"]: clip_layers(c["path"], a.encoder) for c in clips}
    names = layer_names(len(next(iter(layers.values()))))
    results: dict[str, dict] = {"loo": {}, "shippable": {}}

    def gauge(name: str, build) -> None:
        rows = person_rows(groups, build)
        results["loo"][name] = leave_one_out({g: r for g, r in rows.items() if g != "grid_s1"}, a.lam)
        results["shippable"][name] = transfer(rows, shippable, a.lam)
        print(name, "LOO", summarise(results["loo"][name]), "| shippable →", summarise(results["shippable"][name]),
              flush=True)
    for k, name in enumerate(names):
        gauge(name, lambda c, k=k: design(layers[c["path"]][k], c["fps"], len(c["truth"])))
    bases = [pca_basis([layers[p][k] for p in layers], 64) for k in range(len(names))]
    gauge("mix_all", lambda c: design(np.concatenate([(layers[c["path"]][k] - mu) @ v for k, (mu, v) in enumerate(bases)],
                                                     1), c["fps"], len(c["truth"])))
    ranked = sorted(names, key=lambda n: -summarise(results["loo"][n])["all"]["lag0"])[:2]
    pair = sorted(names.index(n) for n in ranked)
    gauge("mix_best2", lambda c: design(np.concatenate([layers[c["path"]][k] for k in pair], 1), c["fps"], len(c["truth"])))
    out = dict(stamp(), encoder=a.encoder, lam=a.lam, offsets_100hz=OFFS.tolist(), best2=[names[k] for k in pair],
               people={g: len(cs) for g, cs in groups.items()}, shippable=sorted(shippable), results=results,
               summary={k: {n: summarise(r) for n, r in v.items()} for k, v in results.items()})
    publish("layer_ceiling" + ("" if a.encoder == "tiny.en" else f"_{a.encoder}"), out, page(out))


def summarise(r: dict[str, dict]) -> dict:
    """Median lag-0 and best-lag correlation per set (strangers, people, corpus, all) and GRID s4's own."""
    sets = {"strangers": "stranger:", "people": "person:", "corpus": "corpus:", "all": ""}
    out = {}
    for s, pre in sets.items():
        v = [x for g, x in r.items() if g.startswith(pre)]
        if v:
            out[s] = dict(lag0=float(np.median([x["lag0"] for x in v])), best=float(np.median([x["best"] for x in v])),
                          min_lag0=float(min(x["lag0"] for x in v)), n=len(v))
    if "person:grid_s4" in r:
        out["grid_s4"] = r["person:grid_s4"]
    return out


def page(out: dict) -> str:
    """The page: a plot of each front end's medians per set under both protocols, and the tables."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    protocols = {"loo": "ceiling: trained on every other person (LOO)",
                 "shippable": "transfer: trained on shippable footage only"}
    names = list(out["summary"]["loo"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for ax, (key, title) in zip(axes, protocols.items()):
        sets = [s for s in ("strangers", "people", "corpus", "grid_s4") if s in out["summary"][key][names[0]]]
        for j, st in enumerate(sets):
            ax.bar(np.arange(len(names)) + (j - len(sets) / 2 + 0.5) * 0.8 / len(sets),
                   [out["summary"][key][n][st]["lag0"] for n in names], 0.8 / len(sets), label=st)
        ax.set_xticks(range(len(names)), names, rotation=25)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("read-out corr with tracked opening, lag 0")
    fig.tight_layout()
    png = "layer_ceiling" + ("" if out["encoder"] == "tiny.en" else f"_{out['encoder']}") + ".png"
    fig.savefig(ROOT / "docs" / png, dpi=110)
    plt.close(fig)
    lines = [f"# Where articulation lives in Whisper {out['encoder']}: the read-out per layer", "",
             f"Written by `python bench/layer_ceiling.py` (commit {out['commit']}, {out['date']}, {out['machine']}); "
             f"{len(out['people'])} people, ridge λ = {out['lam']}, context ±300 ms. A linear read-out of one "
             "front end's states, correlated with a held-out person's tracked inner-lip opening (median over a set's "
             "people; lag 0 / best lag within ±5 frames). `final` is the encoder's last layer (for tiny.en what the shipped `whisper` front end reads); "
             f"`mix_best2` joins {' and '.join(out['best2'])}; `mix_all` joins every layer's first 64 principal "
             "components.", "",
             f"![read-out per layer]({png})", ""]
    for key, title in protocols.items():
        sets = [s for s in ("strangers", "people", "corpus", "grid_s4") if s in out["summary"][key][names[0]]]
        lines += [f"## {title[0].upper()}{title[1:]}", ""]
        if key == "shippable":
            lines += ["Trained on: " + ", ".join(f"`{g}`" for g in out["shippable"]) + "; scored on everyone else.", ""]
        lines += ["| front end | " + " | ".join(sets) + " |", "|---|" + "---|" * len(sets)]
        for n in names:
            lines.append(f"| {n} | " + " | ".join(f"{out['summary'][key][n][st]['lag0']:.2f} / "
                                                  f"{out['summary'][key][n][st]['best']:.2f}" for st in sets) + " |")
        lines.append("")
    lines += ["## Per person (lag 0; ceiling / transfer)", "", "| person | " + " | ".join(names) + " |",
              "|---|" + "---|" * len(names)]
    for g in out["people"]:
        cells = []
        for n in names:
            lo, tr = out["results"]["loo"][n].get(g), out["results"]["shippable"][n].get(g)
            cells.append(f"{lo['lag0']:.2f}" if lo else "–")
            cells[-1] += f" / {tr['lag0']:.2f}" if tr else " / train"
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
