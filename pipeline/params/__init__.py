"""``params.yaml`` as typed sections, validated once when it is loaded.

One dataclass per section (``data``, ``cluster`` and one per stage), in three rooms:
``preprocess`` (data → whisper), ``training`` (the model stages), ``synthesis`` (synthesize → report);
``section`` holds the value rules every section shares and ``loading`` the file reading. ``load_params`` reads the
file, checks every key against its section's fields — an unknown key, a missing section, a
value of the wrong type or outside its allowed choices stops with one line naming
``section.key`` — and returns a ``Params`` whose sections are read as attributes
(``params.ingest.crop_size``). A key the file leaves out takes the default below, which equals
the shipped params.yaml. Code never reads raw dicts of parameters.

What each key means is written once, in ``help.yaml`` beside these modules (prose, which no
stage runs: editing a meaning reruns nothing); ``lipsynth params-doc --write`` renders it into
docs/parameters_reference.md and into params.yaml's comments.

Applications may adjust a loaded tree (``lipsynth speak`` points the preprocessing outputs at
its cache): ``copy.deepcopy`` it and assign attributes; ``check`` re-validates.
"""
from .loading import FEATURE_STORE_OF, PARAMS_FILE, SECTIONS, Params, as_dict, check, front_end_store, load_params, parse
from .preprocess import Cluster, ClusterSecurity, Data, Frontalize, Ingest, Landmarks, Pca, Phonetic, SyntheticSpeaker, Whisper
from .section import Section
from .synthesis import Composite, Evaluate, Report, Speak, Synthesize
from .training import Brand, DelaySweep, Karras, RenderMesh, Train

__all__ = ["FEATURE_STORE_OF", "PARAMS_FILE", "SECTIONS", "Params", "as_dict", "check", "front_end_store",
           "load_params", "parse", "Section", "Cluster", "ClusterSecurity", "Data", "Frontalize", "Ingest",
           "Landmarks", "Pca", "Phonetic", "SyntheticSpeaker", "Whisper", "Composite", "Evaluate", "Report",
           "Speak", "Synthesize", "Brand", "DelaySweep", "Karras", "RenderMesh", "Train"]
