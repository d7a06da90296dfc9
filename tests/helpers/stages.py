"""Run the preprocessing stages in-process on a corpus, with outputs under a temporary folder."""
import yaml

from pipeline.params import as_dict, load_params
from tests.conftest import ROOT


def make_params(tmp_path, videos, cluster=None, **sections):
    """The project's params with ``data.videos`` = videos and the preprocessing outputs in tmp_path."""
    params = load_params(ROOT / "params.yaml")
    params.data.videos = videos
    for stage in ("ingest", "landmarks", "frontalize", "whisper"):
        getattr(params, stage).out = str(tmp_path / f"{stage}.zarr")
    for k, v in (cluster or {}).items():
        setattr(params.cluster, k, v)
    for name, overrides in sections.items():
        for k, v in overrides.items():
            setattr(getattr(params, name), k, v)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(as_dict(params)))
    return params


def run_preprocessing(params, stages=("ingest", "landmarks", "frontalize")):
    from stages.frontalize import frontalize
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    if "ingest" in stages:
        ingest.run(params, params.ingest.out)
    if "landmarks" in stages:
        landmarks.run(params, params.ingest.out, params.landmarks.out)
    if "frontalize" in stages:
        frontalize.run(params, params.ingest.out, params.landmarks.out, params.frontalize.out)
