"""The stage registry: every DVC stage once — its name, the module it runs, its params section,
its ``lipsynth`` subcommand, what it does and the params keys naming its outputs.

The CLI, ``lipsynth personalize``, the benches and the tests read this table; ``dvc.yaml`` is
checked against it (``tests/test_stage_registry.py``: same stages in the same order, each ``cmd``
``python -m <module>``, each stage's outs, metrics and plots exactly ``${key}`` of its outputs).
No stage imports this module, so editing a description reruns nothing.

    from stages.registry import stage
    stage("train").module          # "stages.train.train"
    stage("train").argv("p.yaml")  # [python, "-m", "stages.train.train", "--params", "p.yaml"]
"""
from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class Stage:
    """One DVC stage.

    Attributes
    ----------
    name : str
        the stage's name in dvc.yaml (``train_brand``)
    module : str
        what its ``cmd`` runs with ``python -m`` (``stages.train_brand.train_brand``)
    section : str
        its params.yaml section (``brand``)
    command : str or None
        its ``lipsynth`` subcommand (``train-brand``); None when an application covers it
    description : str
        one line for ``lipsynth --help``
    outputs : tuple of str
        the params keys (``section.key``) of its outs, metrics and plots, in dvc.yaml's order
    """
    name: str
    module: str
    section: str
    command: str | None
    description: str
    outputs: tuple[str, ...]

    def argv(self, params_file) -> list[str]:
        """The command line running this stage on ``params_file`` in this interpreter."""
        return [sys.executable, "-m", self.module, "--params", str(params_file)]

    def main(self, argv: list[str]) -> int:
        """Run the stage in this process (its module's ``main``); returns its exit status."""
        return importlib.import_module(self.module).main(argv)


def _stage(name, module, section, description, *outputs, command: str | None = "") -> Stage:
    return Stage(name, module, section, name.replace("_", "-") if command == "" else command, description, outputs)


STAGES: tuple[Stage, ...] = (
    _stage("synthetic_speaker", "stages.synthetic_speaker.generate", "synthetic_speaker",
           "generate the embedded synthetic speaker corpus", "synthetic_speaker.out_dir"),
    _stage("ingest", "stages.ingest.ingest", "ingest",
           "decode videos: face crops, 16 kHz audio, MFCC features → store/ingest.zarr", "ingest.out"),
    _stage("landmarks", "stages.landmarks.landmarks", "landmarks",
           "dlib 68-point landmarks for every frame → store/landmarks.zarr", "landmarks.out"),
    _stage("frontalize", "stages.frontalize.frontalize", "frontalize",
           "3D model, pose, frontal textures → store/frontalize.zarr", "frontalize.out"),
    _stage("pca", "stages.pca.pca", "pca",
           "18 frontal lip points → 20 PCA coefficients per frame and at 100 Hz → store/pca.zarr", "pca.out"),
    _stage("phonetic", "stages.phonetic.phonetic", "phonetic",
           "pocketsphinx phone indicators per 10 ms → store/phonetic.zarr", "phonetic.out"),
    _stage("whisper", "stages.whisper.whisper", "whisper",
           "Whisper tiny.en encoder states per 10 ms (pretrained on many speakers) → store/whisper.zarr", "whisper.out"),
    _stage("train", "stages.train.train", "train",
           "train the audio → mouth-shape model (train.model) → models/<model>",
           "train.out", "train.metrics", "train.plots"),
    _stage("train_brand", "stages.train_brand.train_brand", "brand",
           "Voice Puppetry (paper 002): entropic facial HMM remapped onto the voice → models/brand",
           "brand.out", "brand.metrics", "brand.plots"),
    _stage("train_karras", "stages.train_karras.train_karras", "karras",
           "Karras et al. (paper 001): autocorrelation conv net with learned emotions → models/karras",
           "karras.out", "karras.metrics", "karras.plots"),
    _stage("render_mesh", "stages.render_mesh.render_mesh", "render_mesh",
           "the Karras model's speaker as an animated textured 3D head for synthesize.audio → MP4, OBJ + point cache",
           "render_mesh.out", "render_mesh.export", command=None),   # `lipsynth render-mesh`: any audio
    _stage("delay_sweep", "stages.train.sweep", "delay_sweep",
           "validation loss of the LSTM for several target delays → plots/", "delay_sweep.plots"),
    _stage("synthesize", "stages.synthesize.synthesize", "synthesize",
           "new audio → re-timed lower-face textures → store/synthesize.zarr", "synthesize.out"),
    _stage("composite", "stages.composite.composite", "composite",
           "synthesized textures into the target video → outputs/…/result.mp4", "composite.out_dir"),
    _stage("evaluate", "stages.evaluate.evaluate", "evaluate",
           "the synthesized video against the ground truth (paper 000 §4.1) → outputs/evaluate, metrics/",
           "evaluate.out", "evaluate.metrics"),
    _stage("report", "stages.report.report", "report",
           "regenerate the HTML report (report.out/index.html), print its path; --open", "report.out"),
)
BY_NAME = {s.name: s for s in STAGES}
# a person's stores, in order, before a model trains on them (personalize, base models, benches)
PREPROCESSING = ("ingest", "landmarks", "frontalize", "pca", "whisper")


def stage(name: str) -> Stage:
    """The registered stage called ``name`` (dvc.yaml's name); KeyError naming the known ones."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise KeyError(f"no stage {name!r}; the stages: {', '.join(BY_NAME)}") from None
