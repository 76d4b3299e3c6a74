"""Exception hierarchy for lidarcal.

Every error a user can cause derives from :class:`LidarcalError`; the ones caused by bad
input are also :class:`ValueError` so that generic callers can catch them.  Messages name
the file, the variable, what was expected and what was found.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable


class LidarcalError(Exception):
    """Base class of every error lidarcal raises on purpose."""


class InputError(LidarcalError, ValueError):
    """An input file or value cannot be used as given."""


class MissingVariableError(InputError):
    """A required variable or column is absent."""


class UnitError(InputError):
    """A quantity has missing, unparsable or incompatible units."""


class ValidationError(InputError):
    """An artefact violates its schema; carries every problem found."""

    def __init__(self, problems: Iterable[str], source: str = "<dataset>"):
        self.problems = list(problems)
        self.source = source
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"{source}: {len(self.problems)} problem(s) found:\n{lines}")


class SchemaError(InputError):
    """A file of ``schemas/`` is malformed: an unknown key, a missing section; names file, variable, key."""


class SealError(InputError):
    """A certificate's seal or signature does not match its contents: its numbers are not shown."""


class ComputeError(LidarcalError, RuntimeError):
    """A parallel computation could not run or finish.

    Every worker was lost, the scheduler is gone, or the workers cannot run this lidarcal.
    """


class OutputExistsError(LidarcalError, FileExistsError):
    """Refusing to overwrite an existing output without an explicit request."""


class DiskFullError(LidarcalError):
    """An output could not be written for want of space; nothing was published."""


def raise_first_bad(bad, message: Callable[[int, int], str], error: type[LidarcalError] = InputError) -> None:
    """Raise ``error(message(i, n))`` when the boolean mask ``bad`` has a True; else nothing.

    ``i`` is the first True's (flat) index, ``n`` the number of Trues: a message names the first
    offending row and says how many there are, so a user fixes them all at once.

    >>> raise_first_bad([False, True, True], lambda i, n: f"row {i + 1} is bad ({n} rows)")
    Traceback (most recent call last):
    ...
    lidarcal.errors.InputError: row 2 is bad (2 rows)
    """
    import numpy as np  # here, not at the top: the CLI's front door imports this module without numpy

    bad = np.asarray(bad, dtype=bool).ravel()
    if bad.any():
        raise error(message(int(np.argmax(bad)), int(bad.sum())))
