"""``lipsynth`` — command-line entry point: one subcommand per pipeline stage, and the applications.

Usually you run the whole pipeline with ``dvc repro`` (only stages whose code, params or inputs
changed are rerun); the subcommands run one stage by hand with the same params file.
"""
from __future__ import annotations

import importlib
import os
import sys

from pipeline.simd_level import cap_for, cpu_flags
from stages.registry import STAGES

# the applications; the stages' subcommands come from the stage registry (stages/registry.py)
APPLICATIONS = {
    "emotions": ("lipsynth.emotions", "list the mined emotion vectors of a Karras model (for --emotion K or K1:K2:t)"),
    "ensemble": ("lipsynth.ensemble", "average several trained models of one speaker into one model folder"),
    "predict-mouth": ("lipsynth.predict_mouth", "per-frame mouth shapes for an audio file from a model folder"),
    "dvc-deps": ("lipsynth.dvc_deps", "check (or --write) the code deps of dvc.yaml's stages, derived from their imports"),
    "params-doc": ("lipsynth.params_doc", "print, --write or --check the parameter reference and params.yaml's comments"),
    "speak": ("lipsynth.speak", "audio + any video of the speaker → lip-synced MP4 (preprocesses the target)"),
    "prepare": ("lipsynth.prepare", "preprocess a target video once (cached) so live and speak start at once"),
    "live": ("lipsynth.live", "audio stream in (stdin/pipe/paced file) → lip-synced video stream out (MPEG-TS, HLS)"),
    "render-mesh": ("lipsynth.render_mesh", "audio → the model's speaker as an animated textured 3D head (front + 3/4 view) → MP4, OBJ + point cache"),
    "cut": ("lipsynth.cut", "one video → consecutive segment files (data.split: time holds out its end)"),
    "personalize": ("lipsynth.personalize", "a new person's footage (~1 min) → a model folder for speak (fine-tunes a base model)"),
}
COMMANDS = {**{s.command: (s.module, s.description) for s in STAGES if s.command}, **APPLICATIONS}
NUMERIC_LIBRARIES = ("numpy", "torch", "ctranslate2", "cv2", "av", "scipy")


def lift_simd_cap(environ=os.environ, loaded=None, flags: set[str] | None = None) -> bool:
    """Undo ``pipeline.simd_level``'s cap (as ``LIPSYNTH_SIMD=native`` would have) while no numeric library has
    loaded (``loaded``: the modules imported so far, default ``sys.modules``); True when lifted. A variable of
    the cap holding another value than the cap's is kept, and so is all of it when ``LIPSYNTH_SIMD`` is set.

    For ``live``: a stream that repeats a frame when the machine falls behind is not reproducible to the byte,
    and the cap costs it latency (the Whisper encoder on MKL's compatible branch: docs/simd_cost.md)."""
    loaded = sys.modules if loaded is None else loaded
    if "LIPSYNTH_SIMD" in environ or any(name in loaded for name in NUMERIC_LIBRARIES):
        return False
    for k, v in cap_for(cpu_flags() if flags is None else flags).items():
        if environ.get(k) == v:
            del environ[k]
    environ["LIPSYNTH_SIMD"] = "native"
    return True


def usage() -> str:
    lines = ["usage: lipsynth COMMAND [options]   (lipsynth COMMAND --help for details)", ""]
    lines += ["stages (each runs one DVC stage with params.yaml; usually `dvc repro` runs them):"]
    lines += [f"  {s.command:<18} {s.description}" for s in STAGES if s.command]
    lines += ["", "applications:"]
    lines += [f"  {name:<18} {desc}" for name, (_, desc) in APPLICATIONS.items()]
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
    if name == "live":
        lift_simd_cap()     # a live stream depends on timing, not reproducible to the byte: every library at full speed
    return importlib.import_module(COMMANDS[name][0]).main(rest)


if __name__ == "__main__":
    raise SystemExit(main())
