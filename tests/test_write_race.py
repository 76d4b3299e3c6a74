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

from lidarcal.cli import main
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


# ------------------------------------------------------------------ issue 27 §4: long names


@pytest.mark.parametrize("length", [230, 255])
def test_every_writer_takes_a_legal_name_up_to_name_max(tmp_path, capsys, length):
    """A destination name of 230-255 bytes is legal; its temporary ``.<name>.<host>-<pid>.<rand>.part``
    went over NAME_MAX, and every writer failed naming the temporary instead of the path given."""
    assert os.pathconf(tmp_path, "PC_NAME_MAX") == 255  # the limit this test is about (ext4, tmpfs)
    stem = "é" * ((length - 3) // 2) + "x" * ((length - 3) % 2)  # two bytes a character: cut at a boundary
    name = f"{stem}.nc"
    assert len(name.encode()) == length
    d = tmp_path / "out"
    d.mkdir()
    assert main(["rwf", "-o", str(d / name)]) == 0
    assert main(["keygen", "-o", str(d / stem[: (length - 4) // 2])]) == 0  # KEY and KEY.pub (4 bytes more)
    key = next(p for p in d.iterdir() if not p.name.endswith((".pub", ".nc")))
    assert len((key.name + ".pub").encode()) <= 255
    records = tmp_path / "records.nc"
    from analysis_factories import make_records

    from lidarcal.analysis import budget
    from lidarcal.io import write_artefact

    make_records(n=200).to_netcdf(records)
    bud = write_artefact(budget(open_artefact(records)), tmp_path / "b.nc")
    cert = d / f"{stem[:-1]}c.nc"
    assert main(["certificate", "--budget", str(bud), "--demonstration", "-o", str(cert)]) == 0
    assert main(["dcc", str(cert), "-o", str(d / f"{stem[:-1]}c.xml")]) == 0
    assert main(["table", str(cert), "-o", str(d / f"{stem[:-1]}c.csv")]) == 0
    names = sorted(p.name for p in d.iterdir())
    assert not [n for n in names if n.endswith(".part")]  # no temporary left
    assert len(names) == 6 and all(len(n.encode()) <= 255 for n in names)
    # a temporary's name fits, and a killed writer's is still recognised as this path's
    tmp = part_path(d / name)
    assert len(tmp.name.encode()) <= 255 and tmp.name.startswith(".é")
    assert remove_stale_parts(d / name) == []  # this process is alive: never touched
    dead = tmp.with_name(tmp.name.replace(f"-{os.getpid()}.", "-4194303."))
    tmp.rename(dead)
    assert remove_stale_parts(d / name) == [dead] and not dead.exists()


def test_a_name_over_name_max_is_refused_naming_the_path(tmp_path, capsys):
    name = "n" * 256 + ".nc"
    assert main(["rwf", "-o", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / name}: file name of 259 bytes; the file system of {tmp_path} allows at most 255" \
        in err, err
    assert list(tmp_path.iterdir()) == []
