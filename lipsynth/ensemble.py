"""``lipsynth ensemble`` — average several trained models of one speaker into one model folder.

    lipsynth ensemble --out models/lstm_ensemble models/lstm runs/seed1/models/lstm [...]

The members are model folders of any family trained on the same store (one mouth PCA basis, one
speaker); the ensemble predicts the mean of their mouth shapes and answers every command that
takes ``--model`` (``speak``, ``predict-mouth``, ``render-mesh``, ``synthesize.model``). It is
self-contained: the members' files and the first member's speaker (candidate bank) are copied in.
Train members with other seeds (``dvc exp run -S train.seed=1``) or front ends.
"""
from __future__ import annotations

import argparse
import logging

from pipeline.models import model_ensemble
from pipeline.io.runner import run_main, setup_logging

log = logging.getLogger("lipsynth.ensemble")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth ensemble", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("members", nargs="+", help="trained model folders (at least two)")
    ap.add_argument("--out", required=True, help="the ensemble folder to write (replaced when it succeeds)")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)

    def go():
        cfg = model_ensemble.write(a.out, a.members)
        log.info("%s: ensemble of %d models (%s), PCA basis %s", a.out, len(cfg["members"]),
                 ", ".join(cfg["families"]), cfg["pca_fingerprint"])
    return run_main(go)


if __name__ == "__main__":
    raise SystemExit(main())
