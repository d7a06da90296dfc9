"""Run the preprocessing stages in-process on a corpus, with outputs under a temporary folder."""
import copy

import yaml

from pipeline.params import load_params
from tests.conftest import ROOT


def make_params(tmp_path, videos, cluster=None, **sections):
    params = copy.deepcopy(load_params(ROOT / "params.yaml"))
    params["data"]["videos"] = videos
    for stage in ("ingest", "landmarks", "frontalize"):
        params[stage]["out"] = str(tmp_path / f"{stage}.zarr")
    params["cluster"].update(cluster or {})
    for name, overrides in sections.items():
        params[name].update(overrides)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    return params


def run_preprocessing(params, stages=("ingest", "landmarks", "frontalize")):
    from stages.frontalize import frontalize
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    if "ingest" in stages:
        ingest.run(params, params["ingest"]["out"])
    if "landmarks" in stages:
        landmarks.run(params, params["ingest"]["out"], params["landmarks"]["out"])
    if "frontalize" in stages:
        frontalize.run(params, params["ingest"]["out"], params["landmarks"]["out"], params["frontalize"]["out"])
