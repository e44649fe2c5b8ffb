"""Errors that reach the user as one clear line.

Every problem with the user's input is raised as :class:`InputError` naming the file (or flag) and the
problem; the CLI prints ``lift3d: error: <file>: <problem>`` and exits with code 2 (a traceback only with
``--debug``). Programming errors stay ordinary exceptions.
"""

from __future__ import annotations

from pathlib import Path


class Lift3DError(Exception):
    """Base class of the errors the CLI reports as one line with exit code 2."""


class InputError(Lift3DError, ValueError):
    """Bad input: a missing, unreadable or malformed file, or an invalid option.

    A :class:`ValueError` too, so a caller's ``except ValueError`` catches it as it would any bad value.

    Parameters
    ----------
    where : str or Path
        The file (or flag) that is wrong. Shown first so the user knows where to look.
    problem : str
        What is wrong, in one line.

    Examples
    --------
    >>> str(InputError("scene/transforms.json", "frames[3].transform_matrix is not finite"))
    'scene/transforms.json: frames[3].transform_matrix is not finite'
    >>> isinstance(InputError("--steps", "must be positive"), ValueError)
    True
    """

    def __init__(self, where: str | Path, problem: str):
        self.where = str(where)
        self.problem = problem
        super().__init__(f"{self.where}: {problem}")


class TrainingDiverged(Lift3DError):
    """Training produced non-finite losses repeatedly; the last good checkpoint is intact."""
