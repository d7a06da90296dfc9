"""lipsynth applications: the command line and ``speak``, on top of the stages and ``pipeline``."""
