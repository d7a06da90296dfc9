"""Audio → mouth-shape models: the mouth PCA space, each family's network and inference, the model
folder (save/load/check per family), ensembles, the speaker bank, and ``mouth_prediction`` — the
one interface (``predict_mouth``) every family answers (docs/extending.md)."""
