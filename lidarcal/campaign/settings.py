"""How a campaign's simulation is executed: one frozen value, passed as one argument.

Where the chunks run, how many periods each holds, where finished chunks are kept and how the
run reports itself never change a number (:mod:`lidarcal.campaign.run`: seeds are keyed by
period, not by chunk or worker).  So these settings travel together, apart from what *is*
simulated: the command line builds one :class:`Execution` from its options
(:func:`lidarcal.cli.options.execution_of`), and :func:`~lidarcal.campaign.simulate_campaign`,
:func:`~lidarcal.campaign.run.simulate_replicas`, the adaptive replicas, the model-form runs,
``diagnose``, ``compare`` and ``smc`` take it as their ``execution`` argument.  What of it goes
into an artefact's provenance is said by one method, :meth:`Execution.record`.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

from lidarcal.campaign.progress import Progress
from lidarcal.errors import InputError

__all__ = ["Execution", "WORKER_TIMEOUT", "CONNECT_TIMEOUT", "DEFAULT_CHUNK"]

#: Periods per Dask task unless told otherwise.
DEFAULT_CHUNK = 64
#: Seconds to wait for a remote scheduler to answer.
CONNECT_TIMEOUT = 5.0
#: Seconds a distributed run waits while no worker is connected (none yet, or all lost) before
#: it fails with :class:`~lidarcal.errors.ComputeError`.
WORKER_TIMEOUT = 60.0


@dataclasses.dataclass(frozen=True)
class Execution:
    """Where and how a simulation runs; none of it changes the result.

    Parameters
    ----------
    chunk : int
        Periods per Dask task.
    scheduler : None, str or distributed.Client
        ``None``/``"processes"`` a local process pool, ``"threads"``, ``"synchronous"``,
        ``"local"`` (a ``distributed.LocalCluster``), an address ``"tcp://host:port"`` or a
        ``distributed.Client`` (:mod:`lidarcal.campaign.run`).
    workers : int, optional
        Worker processes/threads of the local schedulers (default: the CPU count).
    workdir : path, optional
        The resumable chunk cache (created if missing).
    progress : bool, str or Progress
        How the run reports itself; kept as a :class:`~lidarcal.campaign.progress.Progress`
        (:meth:`Progress.of`: True a bar, ``"lines"`` a line every 30 s, False nothing).
    connect_timeout : float
        Seconds to wait for a remote scheduler before :class:`~lidarcal.errors.InputError`.
    worker_timeout : float
        With ``dask.distributed``: seconds to wait while no worker is connected before
        :class:`~lidarcal.errors.ComputeError`.

    >>> run = Execution(chunk=8, scheduler="synchronous")
    >>> run.record(), run.record(where=False)
    ({'chunk': 8, 'scheduler': 'synchronous', 'workers': None}, {'chunk': 8})
    >>> Execution.of({"workers": 2}).workers, Execution.of(None) == Execution()
    (2, True)
    """

    chunk: int = DEFAULT_CHUNK
    scheduler: Any = None
    workers: int | None = None
    workdir: str | os.PathLike | None = None
    progress: Progress = dataclasses.field(default_factory=lambda: Progress.of(False))
    connect_timeout: float = CONNECT_TIMEOUT
    worker_timeout: float = WORKER_TIMEOUT

    def __post_init__(self) -> None:
        object.__setattr__(self, "progress", Progress.of(self.progress))
        if int(self.chunk) < 1:
            raise InputError(f"chunk must be >= 1 period; got {int(self.chunk)}")
        object.__setattr__(self, "chunk", int(self.chunk))

    @classmethod
    def of(cls, execution: Execution | Mapping[str, Any] | None) -> Execution:
        """Return ``execution`` as an :class:`Execution` (None: the defaults; a mapping: its fields)."""
        if isinstance(execution, Execution):
            return execution
        if execution is None:
            return cls()
        if isinstance(execution, Mapping):
            names = {f.name for f in dataclasses.fields(cls)}
            unknown = sorted(set(execution) - names)
            if unknown:
                raise InputError(f"execution settings {unknown} unknown; expected some of {sorted(names)}")
            return cls(**execution)
        raise InputError(f"execution must be an Execution, a mapping of its fields or None; got "
                         f"{type(execution).__name__}")

    def replace(self, **changes: Any) -> Execution:
        """Return these settings with ``changes`` (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def labelled(self, label: str) -> Execution:
        """Return these settings, reporting their progress as ``label`` (:meth:`Progress.labelled`)."""
        return self.replace(progress=self.progress.labelled(label))

    def record(self, *, where: bool = True) -> dict[str, Any]:
        """Return what an artefact's provenance records of these settings (in ``lidarcal_config``).

        Simulated records say where they were simulated (``where``): the chunk size, the
        scheduler (its name, or ``"distributed.Client"``) and the workers, unset or not.  An
        analysis that simulates on the way (``diagnose``, ``compare``, ``smc``) records only the
        chunk size and the workers it was given (``where=False``).  Neither records the chunk
        cache, the progress or the timeouts.
        """
        if not where:
            return {"chunk": self.chunk, **({"workers": self.workers} if self.workers is not None else {})}
        scheduler = self.scheduler if isinstance(self.scheduler, str | type(None)) else "distributed.Client"
        return {"chunk": self.chunk, "scheduler": scheduler, "workers": self.workers}
