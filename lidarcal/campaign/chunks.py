"""One chunk of a campaign: simulate consecutive periods, cache the result atomically.

A chunk is one :class:`ChunkTask`, built once by :mod:`lidarcal.campaign.run`: which periods,
their inputs and seed keys, and its cache entry (``key``, named by :func:`chunk_key`, and the
folder it is kept in).  :meth:`ChunkTask.cached` reads a finished chunk back; :func:`run_chunk`
simulates one and keeps it.  :func:`run_chunk` runs inside a Dask task (thread, process or
``dask.distributed`` worker), so the task is plain data (numpy arrays, the model as a dict,
passed beside it because every chunk of a run shares it) and the function is pure: a
period's result depends only on the model, its conditions and the seed entropy
``(base_seed, period_key)``, where :func:`period_keys` derives the key from the period's
timestamp — never on the chunk it lands in, its position in the file, the worker or the order
of execution.  That is what makes any chunking, any number of workers and any split of a
conditions file into parts bit-identical.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lidarcal.campaign.workers import one_blas_thread
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.errors import InputError
from lidarcal.io import disk_full, part_path, publish, remove_stale_parts
from lidarcal.lidar import LidarModel, simulate_period

__all__ = ["OUTPUTS", "ChunkTask", "chunk_key", "chunk_path", "finished_chunks", "load_chunk", "period_keys",
           "run_chunk", "seed_entropy"]

#: Per-height outputs of :func:`lidarcal.lidar.simulate_period` stored by the campaign.
OUTPUTS = (
    "lidar_wind_speed",
    "lidar_wind_speed_scalar",
    "lidar_wind_speed_vector",
    "reference_wind_speed",
    "availability",
)

#: Inputs passed to the engine, in the order of the conditions contract.
INPUTS = CONDITION_NAMES

_FORMAT = 2  # bump when the chunk file layout or the result of a chunk changes meaning (2: timestamp keys)


def period_keys(times: np.ndarray) -> np.ndarray:
    """Seed key of each period: whole seconds of its timestamp since 1970-01-01T00:00:00 (int64).

    A period's random streams are keyed by this (and its height), never by its position in the
    conditions file, so a period gets the same draws in any file it appears in.
    """
    t = np.asarray(times)
    if t.dtype.kind != "M":
        raise TypeError(f"period times must be numpy datetime64; got {t.dtype}")
    return t.astype("datetime64[s]").astype(np.int64)


def seed_entropy(base_seed: int, key: int, replica: int = 0) -> tuple[int, ...]:
    """``(base_seed, key)`` as SeedSequence entropy (non-negative: times before 1970 wrap modulo 2**64).

    Monte Carlo replica ``replica`` >= 1 of the period (JCGM 101 7.9, docs/seeds.md) draws from
    ``(base_seed, replica, key)``; replica 0 keeps ``(base_seed, key)``, the streams of a run
    without replicas.
    """
    if int(replica) == 0:
        return int(base_seed), int(key) % 2**64
    return int(base_seed), int(replica), int(key) % 2**64


def chunk_key(
    conditions_checksum: str,
    model: dict,
    base_seed: int,
    start: int,
    stop: int,
    heights: np.ndarray,
    duration: float,
    los_periods: tuple[int, ...],
    keys: np.ndarray | None = None,
    extra: dict | None = None,
) -> str:
    """SHA-256 naming a chunk's result: same key ⇔ same inputs ⇔ same numbers.

    ``keys`` are the chunk's period seed keys (:func:`period_keys`); the conditions checksum
    with the chunk bounds fixes its input values.  ``extra`` (a replica's number and the cells it
    simulates) enters the key only when given, so replica 0 keeps its keys.
    """
    los = [int(i) for i in los_periods if start <= i < stop]
    text = json.dumps(
        {
            "format": _FORMAT,
            "conditions": conditions_checksum,
            "model": model,
            "base_seed": int(base_seed),
            "start": int(start),
            "stop": int(stop),
            "heights": [float(h) for h in heights],
            "duration": float(duration),
            "los": los,
            "period_keys": [int(k) for k in (keys if keys is not None else [])],
            **(extra or {}),
        },
        sort_keys=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()


def make_workdir(workdir: str | os.PathLike) -> Path:
    """Create the chunk cache directory (and its parents); a clear error if that cannot be done."""
    path = Path(workdir)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: --workdir must be a directory (the chunk cache); it is a file. Give a "
                         f"new or existing directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:  # a parent is a file
        raise InputError(f"{path}: --workdir cannot be created: one of its parents is a file") from None
    except NotADirectoryError:
        raise InputError(f"{path}: --workdir cannot be created: one of its parents is a file") from None
    except OSError as exc:
        raise InputError(f"{path}: --workdir cannot be created ({exc.strerror})") from None
    return path


def chunk_path(workdir: str | os.PathLike, start: int, stop: int, key: str) -> Path:
    """``workdir/chunk-<start>-<stop>-<key16>.npz``."""
    return Path(workdir) / f"chunk-{start:07d}-{stop:07d}-{key[:16]}.npz"


def finished_chunks(workdir: str | os.PathLike) -> int:
    """Count the finished chunk files under ``workdir`` (replica 0 and every ``replica-<r>``)."""
    path = Path(workdir)
    return sum(1 for _ in path.rglob("chunk-*.npz")) if path.is_dir() else 0


def load_chunk(path: Path, key: str, n: int, n_heights: int) -> dict[str, np.ndarray] | None:
    """Return the cached chunk if ``path`` holds a complete result for ``key``; else None."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            out = {name: z[name] for name in z.files if name != "key"}
    except Exception:  # unreadable (cannot happen with atomic writes, but never trust a cache)
        return None
    if any(out.get(name, np.empty(0)).shape != (n, n_heights) for name in OUTPUTS):
        return None
    return out


def _save_atomic(path: Path, key: str, result: dict[str, np.ndarray]) -> None:
    # a cache entry is named by its key, so two workers writing one chunk write the same
    # numbers: the later rename may replace the earlier (publish with overwrite).  Temporaries
    # of killed workers are recognised by their pid and removed (lidarcal.io.part_path).
    remove_stale_parts(path)
    tmp = part_path(path)
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, key=np.asarray(key), **result)
            fh.flush()
            os.fsync(fh.fileno())
        publish(tmp, path, overwrite=True)
    except OSError as exc:
        raise disk_full(exc, path) or exc from None  # a full disk: one clear message
    finally:
        if tmp.exists():
            tmp.unlink()


@dataclass(frozen=True)
class ChunkTask:
    """One chunk as a worker simulates it: consecutive (or selected) periods at the campaign's heights.

    Plain data, so it pickles to any worker.  ``inputs`` are the six :data:`INPUTS` (n, h);
    ``valid`` (n, h) the cells to simulate; ``period_index`` (n,) the periods' positions in the
    conditions (they name the stored LOS series); ``period_key`` (n,) their seed keys
    (:func:`period_keys`); ``los`` (n,) the periods whose LOS series are kept; ``replica`` the
    Monte Carlo replica (0: the campaign's own streams).  ``key`` (:func:`chunk_key`), ``start``
    and ``stop`` name the chunk's cache entry in ``workdir`` (none without one); ``name`` is its
    Dask task.
    """

    name: str
    heights: np.ndarray
    inputs: dict[str, np.ndarray]
    valid: np.ndarray
    period_index: np.ndarray
    period_key: np.ndarray
    los: np.ndarray
    base_seed: int
    duration: float
    key: str
    start: int
    stop: int
    replica: int = 0
    workdir: str | None = None

    @property
    def periods(self) -> int:
        """Periods the chunk simulates."""
        return self.stop - self.start

    def cached(self) -> dict[str, Any] | None:
        """Return the chunk's result kept in ``workdir`` by an earlier run (LOS series included), or None."""
        if self.workdir is None:
            return None
        found = load_chunk(chunk_path(self.workdir, self.start, self.stop, self.key), self.key, self.periods,
                           len(self.heights))
        return None if found is None else unflatten_los(found)


def run_chunk(task: ChunkTask, model: dict[str, Any]) -> dict[str, Any]:
    """Simulate the periods of one chunk (runs on a worker); keep the result if ``task.workdir``.

    ``model`` is the full dict, ``LidarModel.to_dict(residuals=True)``: a worker needs every bench
    residual to resample bit for bit.  Returns ``{output: (n, h) array}`` plus ``los``
    (``{period_index: {name: array}}``).
    """
    lidar = LidarModel.from_dict(model)
    replica = task.replica
    heights = np.asarray(task.heights, dtype=float)
    valid = np.asarray(task.valid, dtype=bool)
    n, nh = valid.shape
    out = {name: np.full((n, nh), np.nan) for name in OUTPUTS}
    los: dict[int, dict[str, np.ndarray]] = {}
    # one BLAS thread whatever runs this (process pool, threads, synchronous, any dask worker):
    # BLAS's multi-threaded sums differ in the last bits (docs/cluster.md)
    with one_blas_thread():
        for i in range(n):
            cols = np.flatnonzero(valid[i])
            if cols.size == 0:
                continue
            pidx = int(task.period_index[i])
            want_los = bool(task.los[i])
            res = simulate_period(
                # in replica r >= 1 of the mixture noise model each period draws p_bad(CNR) (docs/seeds.md)
                lidar.for_trial(task.base_seed, replica, task.period_key[i]),
                heights=heights[cols],
                **{name: np.asarray(task.inputs[name][i, cols], dtype=float) for name in INPUTS},
                seed=seed_entropy(task.base_seed, task.period_key[i], replica),
                duration=float(task.duration),
                return_los=want_los,
            )
            for name in OUTPUTS:
                out[name][i, cols] = res[name]
            if want_los:
                los[pidx] = {"columns": cols,
                             **{k: np.asarray(v) for k, v in res.items() if k not in OUTPUTS}}
    if task.workdir:
        flat = dict(out)
        for pidx, extra in los.items():
            for k, v in extra.items():
                flat[f"los__{pidx}__{k}"] = v
        _save_atomic(chunk_path(task.workdir, task.start, task.stop, task.key), task.key, flat)
    return {**out, "los": los}


def unflatten_los(cached: dict[str, np.ndarray]) -> dict[str, Any]:
    """Turn a cached chunk's ``los__<period>__<name>`` entries back into the ``los`` mapping."""
    los: dict[int, dict[str, np.ndarray]] = {}
    out: dict[str, Any] = {}
    for name, value in cached.items():
        if name.startswith("los__"):
            _, pidx, k = name.split("__", 2)
            los.setdefault(int(pidx), {})[k] = value
        else:
            out[name] = value
    out["los"] = los
    return out
