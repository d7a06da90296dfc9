"""Audio → per-frame features. ``front_ends`` names what a model reads (``train.features``); a new
front end is a module here plus a name in ``front_ends`` (docs/extending.md)."""
