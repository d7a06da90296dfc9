"""params.yaml is read once into typed sections; mistakes stop with one line naming the key."""
import subprocess

import pytest
import yaml

from pipeline.errors import ParameterError
from pipeline.params import Params, as_dict, load_params, parse
from tests.conftest import ROOT
from stages.registry import stage


def shipped():
    return yaml.safe_load((ROOT / "params.yaml").read_text())


def test_the_shipped_params_file_equals_the_code_defaults():
    """A key left out of a params file means the shipped value, never a different hidden one."""
    assert as_dict(load_params(ROOT / "params.yaml")) == as_dict(Params())
    assert set(shipped()) == set(as_dict(Params()))
    for name, section in shipped().items():
        assert set(section) == set(as_dict(getattr(Params(), name))), f"{name}: keys differ from pipeline/params/"


def test_sections_are_typed_attributes():
    p = load_params(ROOT / "params.yaml")
    assert p.ingest.crop_size == "auto" and p.synthesize.teeth_upper is None and p.train.baselines is True


@pytest.mark.parametrize("edit, message", [
    (lambda t: t["ingest"].update(crop_sise=128), r"unknown key ingest\.crop_sise"),
    (lambda t: t["ingest"].update(crop_size="big"), r"ingest\.crop_size='big': expected an int or auto"),
    (lambda t: t["frontalize"].update(texture_size=1.5), r"frontalize\.texture_size=1\.5: expected int or str"),
    (lambda t: t["train"].update(baselines=1), r"train\.baselines=1: expected bool"),
    (lambda t: t["synthesize"].update(teeth_upper=2.5), r"synthesize\.teeth_upper=2\.5: expected int or null"),
    (lambda t: t["synthesize"].update(retarget="sometimes"), r"synthesize\.retarget='sometimes': choose one of"),
    (lambda t: t["data"].update(on_bad_input="ignore"), r"data\.on_bad_input='ignore'"),
    (lambda t: t.update(frontalise={}), r"unknown section 'frontalise'"),
    (lambda t: t.update(pca=[1, 2]), r"section 'pca' must be a mapping"),
    # values (each section's validate()): bounds, then rules across keys
    (lambda t: t["train"].update(steps=0), r"train\.steps=0: must be at least 1"),
    (lambda t: t["pca"].update(n_components=40), r"pca\.n_components=40: must be in \[1, 36\]"),
    (lambda t: t["data"].update(val_fraction=1.0), r"data\.val_fraction=1\.0: must be in \[0, 1\)"),
    (lambda t: t["ingest"].update(crop_size=226), r"ingest\.crop_size=226: must be a multiple of 4"),
    (lambda t: t["ingest"].update(max_crop_size=200), r"ingest\.max_crop_size=200: must be a multiple of 16, at least 224"),
    (lambda t: t["whisper"].update(overlap_seconds=6), r"whisper\.overlap_seconds=6: must be between 0 and half"),
    (lambda t: t["whisper"].update(window_seconds=40), r"whisper\.window_seconds=40: the encoder takes windows of 1–30 s"),
    (lambda t: t["train"].update(vtlp_warps=[0.9]), r"train\.vtlp_warps / pitch_shifts='whisper': augment MFCC"),
    (lambda t: t["train"].update(features="mfcc", pitch_shifts=[20]), r"train\.pitch_shifts=20: is not a shift"),
    (lambda t: t["composite"].update(crf=60), r"composite\.crf=60: must be in \[0, 51\]"),
])
def test_a_mistake_names_the_key(edit, message):
    tree = shipped()
    edit(tree)
    with pytest.raises(ParameterError, match=message):
        parse(tree, "p.yaml")


def test_missing_keys_take_the_defaults_and_ints_are_floats():
    p = parse({"frontalize": {"focal_factor": 2}, "train": {"steps": 3}})
    assert p.frontalize.focal_factor == 2 and p.train.steps == 3 and p.train.hidden == 60


def test_a_stage_refuses_a_bad_params_file_with_one_line(tmp_path):
    tree = shipped()
    tree["landmarks"]["detect_evry"] = 10
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(tree))
    r = subprocess.run(stage("landmarks").argv(tmp_path / "p.yaml"),
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"lipsynth: error: {tmp_path / 'p.yaml'}: unknown key landmarks.detect_evry "
                                             f"(known keys: {', '.join(sorted(as_dict(Params().landmarks)))})"]


def test_stage_main_records_the_wall_time_of_a_stage_that_succeeds_only(tmp_path, monkeypatch):
    import json
    from pipeline.errors import LipsynthError
    from pipeline.io.runner import stage_main
    monkeypatch.chdir(tmp_path)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(shipped()))
    assert stage_main("lipsynth delay-sweep", "", lambda p: None, []) == 0

    def fail(p):
        raise LipsynthError("no")
    assert stage_main("lipsynth train-karras", "", fail, []) == 2
    table = json.loads((tmp_path / "logs" / "stage_seconds.json").read_text())
    assert set(table) == {"delay_sweep"} and 0 <= table["delay_sweep"] < 5
    assert not list((tmp_path / "logs").glob("*.tmp-*"))


def test_the_train_stage_depends_on_exactly_the_store_its_front_end_reads():
    from pipeline.params import front_end_store
    from stages.train.train import feature_store
    p = load_params(ROOT / "params.yaml")
    assert p.train.feature_store == front_end_store(p) == front_end_store(as_dict(p)) == p.whisper.out
    assert feature_store(p) == dict(phonetic_path=None, whisper_path=p.whisper.out)
    p.train.features = "mfcc+phonetic"
    with pytest.raises(ParameterError, match=r"set train.feature_store: store/phonetic.zarr"):
        feature_store(p)
    p.train.feature_store = p.phonetic.out
    assert feature_store(p) == dict(phonetic_path=p.phonetic.out, whisper_path=None)
    p.train.features, p.train.feature_store = "mfcc", p.ingest.out
    assert feature_store(p) == dict(phonetic_path=None, whisper_path=None)
    deps = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["train"]["deps"]
    assert "${train.feature_store}" in deps and not {"${phonetic.out}", "${whisper.out}"} & set(deps)
