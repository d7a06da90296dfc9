"""``lipsynth`` — command-line entry point. Each subcommand is one pipeline stage.

Usually you run the whole pipeline with ``dvc repro`` (only stages whose code, params or inputs
changed are rerun); the subcommands run one stage by hand with the same params file.
"""
from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "synthetic-speaker": ("stages.synthetic_speaker.generate", "generate the embedded synthetic speaker corpus"),
    "ingest": ("stages.ingest.ingest", "decode videos: face crops, 16 kHz audio, MFCC features → store/ingest.zarr"),
    "landmarks": ("stages.landmarks.landmarks", "dlib 68-point landmarks for every frame → store/landmarks.zarr"),
    "frontalize": ("stages.frontalize.frontalize", "3D model, pose, frontal textures → store/frontalize.zarr"),
    "pca": ("stages.pca.pca", "18 frontal lip points → 20 PCA coefficients per frame and at 100 Hz → store/pca.zarr"),
    "phonetic": ("stages.phonetic.phonetic", "pocketsphinx phone indicators per 10 ms → store/phonetic.zarr"),
    "whisper": ("stages.whisper.whisper", "Whisper tiny.en encoder states per 10 ms (pretrained on many speakers) → store/whisper.zarr"),
    "train": ("stages.train.train", "train the audio → mouth-shape model (train.model) → models/<model>"),
    "train-brand": ("stages.train_brand.train_brand", "Voice Puppetry (paper 002): entropic facial HMM remapped onto the voice → models/brand"),
    "train-karras": ("stages.train_karras.train_karras", "Karras et al. (paper 001): autocorrelation conv net with learned emotions → models/karras"),
    "emotions": ("lipsynth.emotions", "list the mined emotion vectors of a Karras model (for --emotion K or K1:K2:t)"),
    "delay-sweep": ("stages.train.sweep", "validation loss of the LSTM for several target delays → plots/"),
    "ensemble": ("lipsynth.ensemble", "average several trained models of one speaker into one model folder"),
    "predict-mouth": ("lipsynth.predict_mouth", "per-frame mouth shapes for an audio file from a model folder"),
    "synthesize": ("stages.synthesize.synthesize", "new audio → re-timed lower-face textures → store/synthesize.zarr"),
    "composite": ("stages.composite.composite", "synthesized textures into the target video → outputs/…/result.mp4"),
    "dvc-deps": ("lipsynth.dvc_deps", "check (or --write) the code deps of dvc.yaml's stages, derived from their imports"),
    "params-doc": ("lipsynth.params_doc", "print, --write or --check docs/parameters_reference.md (rendered from pipeline/params/)"),
    "speak": ("lipsynth.speak", "audio + any video of the speaker → lip-synced MP4 (preprocesses the target)"),
    "prepare": ("lipsynth.prepare", "preprocess a target video once (cached) so live and speak start at once"),
    "live": ("lipsynth.live", "audio stream in (stdin/pipe/paced file) → lip-synced video stream out (MPEG-TS, HLS)"),
    "render-mesh": ("lipsynth.render_mesh", "audio → the model's speaker as an animated textured 3D head (front + 3/4 view) → MP4, OBJ + point cache"),
    "cut": ("lipsynth.cut", "one video → consecutive segment files (data.split: time holds out its end)"),
    "personalize": ("lipsynth.personalize", "a new person's footage (~1 min) → a model folder for speak (fine-tunes a base model)"),
    "report": ("stages.report.report", "regenerate the HTML report (report.out/index.html), print its path; --open"),
}


def usage() -> str:
    lines = ["usage: lipsynth COMMAND [options]   (lipsynth COMMAND --help for details)", "", "commands:"]
    lines += [f"  {name:<18} {desc}" for name, (_, desc) in COMMANDS.items()]
    lines += ["", "The whole pipeline: dvc repro   (params in params.yaml; see docs/)"]
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"lipsynth: error: unknown command '{name}'\n\n{usage()}", file=sys.stderr)
        return 2
    return importlib.import_module(COMMANDS[name][0]).main(rest)


if __name__ == "__main__":
    raise SystemExit(main())
