"""Concurrent writers of one new path: exactly one wins, the others get exit 2, nothing is lost.

Real processes, not threads: the race the issue found (two of fifteen trials had both writers
"succeed", one output silently replacing the other) was between processes.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lidarcal.errors import OutputExistsError
from lidarcal.io import atomic_path, open_artefact, part_path, remove_stale_parts

N_WRITERS = 6
TRIALS = 20


def _writer(path: str, barrier, rank: int) -> None:
    """Write 1 MB of ``rank`` to ``path``; all writers publish at the same moment."""
    barrier.wait(timeout=60)  # all pass the "does it exist?" check together
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(bytes([rank]) * 1_000_000)
            barrier.wait(timeout=60)  # every temporary is complete before anyone publishes
    except OutputExistsError:
        os._exit(2)
    os._exit(0)


@pytest.mark.parametrize("trial", range(TRIALS))
def test_one_of_concurrent_writers_wins(tmp_path, trial):
    path = tmp_path / "out.bin"
    ctx = multiprocessing.get_context("fork")
    barrier = ctx.Barrier(N_WRITERS)
    procs = [ctx.Process(target=_writer, args=(str(path), barrier, r)) for r in range(N_WRITERS)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    codes = [p.exitcode for p in procs]
    # every writer passed the existence check before any published (the barrier), so a
    # check-then-rename lets two "succeed" when their checks fall between another's check and
    # rename: about one trial in ten here, so TRIALS trials catch it with probability ~0.9
    assert sorted(codes) == [0] + [2] * (N_WRITERS - 1), codes
    winner = codes.index(0)
    assert path.read_bytes() == bytes([winner]) * 1_000_000  # complete, and the winner's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]  # no temporaries left


def test_concurrent_cli_writers(tmp_path):
    """Several ``lidarcal conditions synthetic`` runs to one new file: one exit 0, the rest 2."""
    out = tmp_path / "c.nc"
    cmd = [sys.executable, "-m", "lidarcal", "conditions", "synthetic", "-n", "50",
           "--heights", "40", "80", "--seed", "1", "-o", str(out)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(4)]
    results = [(p.wait(timeout=180), p.stderr.read()) for p in procs]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2, 2, 2], results
    for code, err in results:
        if code == 2:
            assert "Traceback" not in err and f"{out}" in err and "exists" in err, err
    ds = open_artefact(out, "conditions")  # complete and readable
    assert ds.sizes["time"] == 50
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc"]


def test_stale_parts_of_dead_writers_are_removed(tmp_path):
    path = tmp_path / "out.nc"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that no longer exists (a killed run's)
    mine = part_path(path)
    stale = mine.with_name(mine.name.replace(f"-{os.getpid()}.", f"-{dead.pid}."))
    mine.rename(stale)
    live = part_path(path)  # this process is alive: its temporary must stay
    other = tmp_path / ".out.nc.tmp123.part"  # not ours (no host-pid): never touched
    other.touch()
    unrelated = tmp_path / f".out.nc.x.nc{stale.name[len('.out.nc'):]}"  # another output's name
    unrelated.touch()
    with atomic_path(path) as tmp:
        tmp.write_bytes(b"data")
    assert not stale.exists()
    assert live.exists() and other.exists() and unrelated.exists()
    assert path.read_bytes() == b"data"
    assert remove_stale_parts(path) == []


@pytest.mark.parametrize("overwrite", [False, True])
def test_failed_write_leaves_nothing(tmp_path, overwrite):
    path = tmp_path / "out.nc"
    with pytest.raises(RuntimeError), atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_overwrite_replaces(tmp_path):
    path = tmp_path / "out.nc"
    path.write_bytes(b"old")
    with pytest.raises(OutputExistsError), atomic_path(path) as tmp:
        tmp.write_bytes(b"new")
    assert path.read_bytes() == b"old"
    with atomic_path(path, overwrite=True) as tmp:
        tmp.write_bytes(b"new")
    assert Path(path).read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.nc"]
