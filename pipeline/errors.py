"""Typed errors. Every message names the offending file (or parameter) and the problem."""


class LipsynthError(Exception):
    """Base class for all errors lipsynth reports to the user as one line."""


class ParameterError(LipsynthError):
    """A parameter in params.yaml (or on the command line) is missing or invalid."""


class BadInputError(LipsynthError):
    """An input file cannot be used: no audio, no video, corrupt, no face, too short...

    Parameters
    ----------
    path : str
        The offending file.
    problem : str
        What is wrong with it, in a few words.
    """

    def __init__(self, path, problem):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class NoLipSyncError(BadInputError):
    """The output was written, but most of its frames are the untouched target: no lip sync was made.

    ``speak`` raises it after writing the file (the message says so), so a script sees a non-zero exit.
    """
