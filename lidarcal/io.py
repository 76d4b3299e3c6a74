"""Reading and writing artefacts: atomic, validated, never half-written.

:func:`write_artefact` validates a dataset against its schema, writes it to a temporary
file in the destination directory and renames it into place, so a crash or a bad dataset
never leaves a partial file.  It refuses to replace an existing file unless asked.
:func:`open_artefact` turns every way a file can be unreadable into one clear
:class:`~lidarcal.errors.InputError` naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import shutil
import socket
import stat
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import xarray as xr

from lidarcal.errors import DiskFullError, InputError, OutputExistsError, ValidationError
from lidarcal.provenance import sha256, text_problems
from lidarcal.readback import read_attr, source_name  # source_name: the one answer to "which file was this?"
from lidarcal.schema import validate_dataset

__all__ = [
    "write_artefact", "open_artefact", "atomic_path", "check_writable", "source_name",
    "part_path", "publish", "remove_stale_parts", "write_into", "disk_full", "LOW_SPACE_BYTES",
    "read_image", "open_image",
]


def check_input_file(path: str | os.PathLike, what: str = "file") -> Path:
    """Refuse, before opening it, an input that is missing or not a regular file (a FIFO would hang)."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except OSError as exc:
        raise InputError(f"{path}: {what} cannot be read ({exc.strerror})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a directory; expected a {what}")
    if not stat.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a regular file")
        raise InputError(f"{path}: is {kind}; expected a regular {what} (reading it could block forever)")
    return path


def check_writable(path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Fail early (before any work) if ``path`` exists and may not be replaced."""
    path = Path(path)
    if path.parent.is_dir() and len(path.name.encode()) > _name_max(path.parent):
        raise InputError(f"{path}: file name of {len(path.name.encode())} bytes; the file system of "
                         f"{path.parent} allows at most {_name_max(path.parent)}")
    if path.is_dir():
        raise InputError(f"{path}: output is a directory; expected the path of a file")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path}: file exists; pass overwrite=True (--overwrite) to replace it")
    parent = path.parent
    if not parent.exists():
        raise InputError(f"{path}: output directory {parent} does not exist")
    if not parent.is_dir():
        raise InputError(f"{path}: {parent} is not a directory")
    try:  # a real probe: permission bits say nothing for root or on a read-only file system
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as exc:
        if (full := disk_full(exc, path)) is not None and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise full from None
        raise InputError(f"{path}: output directory {parent} is not writable ({exc.strerror})") from None
    return path


#: Temporary files are ``.<name>.<host>-<pid>.<random>.part`` next to their destination, so a
#: later writer of the same path can recognise those of runs that died and remove them.  (A
#: renderer that insists on its own suffix may end one in ``.png`` instead.)  Writers never nest
#: temporaries; those older versions left (``..<name>.<host>-<pid>.<random>.part.<host>-<pid>.
#: <random>.part``, a temporary of a temporary) are recognised too.
_PART = re.compile(r"(?P<host>[A-Za-z0-9_-]*)-(?P<pid>[0-9]+)\.[A-Za-z0-9_]+\.(?:part|png)")
_NESTED = re.compile(r"(?P<host>[A-Za-z0-9_-]*)-(?P<pid>[0-9]+)\.[A-Za-z0-9_]+\.part\.(?P<inner>.+)")

#: Below this much free space (bytes) in the destination's file system, a failed write is
#: reported as a full disk (:func:`disk_full`): HDF5 says only "HDF error" (or, creating a
#: file, "Permission denied") when it cannot get a block.
LOW_SPACE_BYTES = 8 * 1024 * 1024


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _stale(rest: str, host: str) -> bool:
    """Say whether ``rest`` (a temporary's name after ``.<name>.``) belongs only to dead writers here."""
    m = _PART.fullmatch(rest)
    if m is not None:
        return m["host"] == host and not _pid_alive(int(m["pid"]))
    m = _NESTED.fullmatch(rest)  # a temporary of a temporary (older lidarcal): every writer dead
    return (m is not None and m["host"] == host and not _pid_alive(int(m["pid"]))
            and _stale(m["inner"], host))


def remove_stale_parts(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary files of writers of ``path`` that died (killed runs); return them.

    Only files named by :func:`part_path` on this host whose process no longer exists are
    removed (and the nested ``..<name>.*.part.*.part`` ones older versions left): a live
    writer's temporary (this or another process, or another host sharing the directory) is
    never touched.
    """
    path = Path(path)
    prefixes, host, removed = (_part_prefix(path), f"..{path.name}."), _host(), []
    try:
        candidates = [p for p in path.parent.iterdir() if p.name.startswith(prefixes)]
    except OSError:
        return removed
    for p in candidates:
        nested = p.name.startswith(prefixes[1])
        rest = p.name[len(prefixes[1] if nested else prefixes[0]):]
        if (nested and _NESTED.fullmatch(rest) is None) or not _stale(rest, host):
            continue
        with contextlib.suppress(OSError):
            p.unlink()
            removed.append(p)
    return removed


def _free_bytes(directory: Path) -> int | None:
    try:
        return shutil.disk_usage(directory).free
    except OSError:
        return None


def disk_full(exc: BaseException, path: str | os.PathLike) -> DiskFullError | None:
    """Return the :class:`~lidarcal.errors.DiskFullError` ``exc`` means when writing ``path``, or None.

    An ``ENOSPC``/``EDQUOT`` error is one; so is any other ``OSError`` or ``RuntimeError`` (netCDF's
    "HDF error") raised while the destination's file system has less than
    :data:`LOW_SPACE_BYTES` free.  Call it before the failed temporary is removed: what it
    holds is part of the shortage.
    """
    path = Path(path)
    if isinstance(exc, DiskFullError):
        return None
    cause = _enospc_in_chain(exc)
    if cause is not None:  # e.g. matplotlib's zlib.error while closing a PDF its ENOSPC broke
        exc = cause
    if not isinstance(exc, OSError | RuntimeError):
        return None
    free = _free_bytes(path.parent)
    code = getattr(exc, "errno", None)
    if code not in (errno.ENOSPC, errno.EDQUOT) and (free is None or free >= LOW_SPACE_BYTES):
        return None
    left = f"{free} bytes free in {path.parent}" if free is not None else f"in {path.parent}"
    return DiskFullError(f"no space left on device writing {path} ({left}; {type(exc).__name__}: {exc}); "
                         "nothing was written: free some space and run again")


def _enospc_in_chain(exc: BaseException) -> OSError | None:
    """Return the ENOSPC/EDQUOT ``OSError`` that ``exc`` is, or was raised while handling, if any."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def _name_max(directory: Path) -> int:
    """Longest file name (bytes) the file system of ``directory`` allows (255 where it cannot say)."""
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _tail_bytes() -> int:
    """Return the bytes a temporary's name adds after its prefix: ``<host>-<pid>.<random>.part``.

    The pid counted at its widest (Linux's pid_max is at most 4194304: 7 digits), the random part 8.
    """
    return len(_host().encode()) + len("-4194304.") + 8 + len(".part")


def _part_prefix(path: Path) -> str:
    """Return the start of every temporary of ``path``: ``.<name>.``, or a shortened form that fits.

    A name of up to NAME_MAX bytes is legal for the destination, but ``.<name>.<host>-<pid>.<random>.part``
    would not be: then the name is cut (at a character boundary) and ``~`` and the first 8 hex digits
    of its SHA-256 are appended, so the prefix still belongs to this one destination (what
    :func:`remove_stale_parts` recognises).
    """
    full = f".{path.name}."
    room = _name_max(path.parent) - _tail_bytes()
    if len(full.encode()) <= room:
        return full
    digest = hashlib.sha256(path.name.encode()).hexdigest()[:8]
    keep = path.name.encode()[: max(room - len(f"..~{digest}"), 1)].decode("utf-8", "ignore")
    return f".{keep}~{digest}."


def part_path(path: str | os.PathLike) -> Path:
    """Create and return a new empty temporary file for ``path``, next to it (mode 0600)."""
    path = Path(path)
    prefix = f"{_part_prefix(path)}{_host()}-{os.getpid()}."
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".part", dir=path.parent)
    os.close(fd)
    return Path(tmp)


def publish(tmp: Path, path: Path, *, overwrite: bool = False) -> None:
    """Move the finished temporary ``tmp`` onto ``path``: exactly one of concurrent writers wins.

    With ``overwrite`` the rename replaces whatever is there.  Without it the file is published
    with an exclusive create (a hard link, which fails if ``path`` exists), so of several
    processes writing the same new path one succeeds and the others get
    :class:`~lidarcal.errors.OutputExistsError`; never is one output silently replaced.
    """
    if overwrite:
        os.replace(tmp, path)
        return
    lost = OutputExistsError(f"{path}: file exists: another writer finished it while this one was writing; "
                             "not replaced; pass overwrite=True (--overwrite) to replace it")
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise lost from None
    except OSError:
        # a file system without hard links: reserve the name exclusively, then move the data in
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except FileExistsError:
            raise lost from None
        os.replace(tmp, path)
        return
    tmp.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; publish it onto ``path`` only on success.

    The temporary is removed on failure; temporaries of earlier writers of ``path`` that were
    killed are removed first (:func:`remove_stale_parts`).  Publishing is exclusive unless
    ``overwrite`` (:func:`publish`).  A write that fails for want of space raises
    :class:`~lidarcal.errors.DiskFullError` naming ``path`` (:func:`disk_full`).  Write into
    the temporary directly (:func:`write_into` for an artefact), never through another
    ``atomic_path``: a temporary of a temporary is not recognised as ``path``'s.
    """
    path = check_writable(path, overwrite=overwrite)
    remove_stale_parts(path)
    tmp = part_path(path)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; outputs get ordinary permissions
    try:
        yield tmp
        publish(tmp, path, overwrite=overwrite)
    except Exception as exc:
        full = disk_full(exc, path)  # checked while the temporary still takes its space
        if full is None:
            raise
        raise full from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _encoding(ds: xr.Dataset) -> dict[str, dict]:
    enc: dict[str, dict] = {}
    for name, var in ds.variables.items():
        e: dict = {}
        if name in ds.coords or name.endswith("_bounds") or name in ds.dims:
            e["_FillValue"] = None  # CF: coordinates and bounds carry no fill value
        elif var.dtype.kind == "f":
            e["_FillValue"] = np.nan if var.dtype.itemsize == 8 else np.float32(np.nan)
        elif var.dtype.kind in "iu":
            e["_FillValue"] = None
        if name in ds.dims and var.dtype.kind in "OU":
            # string dimension coordinate (e.g. bench_cube ``los``): write a CF character array;
            # compliance-checker crashes on variable-length string coordinate variables
            e["dtype"] = "S1"
        if var.dtype.kind == "M" and "bounds" in var.attrs and "units" in var.encoding:
            # a time with CF bounds keeps its chosen units; xarray gives the bounds the same ones
            e.update({k: var.encoding[k] for k in ("units", "calendar") if k in var.encoding})
        if var.dtype.kind == "f" and var.ndim >= 1 and var.size > 1000:
            e.update(zlib=True, complevel=4)
        if var.chunks is not None and "time" in var.dims and var.size:
            # a lazy variable is written block of time after block: one HDF5 chunk per block, so each
            # block fills whole chunks (the library's own chunks would span blocks and be cached open)
            e["chunksizes"] = tuple(max(var.chunks[k]) if d == "time" else n
                                    for k, (d, n) in enumerate(zip(var.dims, var.shape, strict=True)))
        enc[name] = e
    return enc


def write_artefact(
    ds: xr.Dataset,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    validate: bool = True,
) -> Path:
    """Validate ``ds`` against its schema and write it atomically to netCDF-4.

    Raises
    ------
    ValidationError
        If the dataset does not satisfy the schema named by its ``lidarcal_artefact``
        attribute; nothing is written.
    OutputExistsError
        If ``path`` exists and ``overwrite`` is false.
    """
    path = check_writable(path, overwrite=overwrite)
    ds = _ready(ds, path, validate=validate)
    with atomic_path(path, overwrite=overwrite) as tmp:
        _to_netcdf(ds, tmp)
    return path


def _to_netcdf(ds: xr.Dataset, tmp: str | os.PathLike) -> None:
    """Write ``ds`` to netCDF-4 in this process.

    Lazy variables (dask arrays: ``smc``'s per-period values and a long campaign's conditions,
    one chunk per block of periods) are computed on this process's synchronous scheduler, never
    on a cluster the caller made dask's default, and written **one block of time at a time**: all
    the variables' chunks of a block are computed together (what they share, once) and written
    before the next block is touched, whatever order dask would choose, into one HDF5 chunk per
    block with a chunk cache of two chunks per variable.  netCDF's default cache (16 MiB per
    variable) kept every chunk written until the file was closed: 100 MB per year of an ``smc``
    campaign, on its own.
    """
    import dask  # deferred: light import of the writers

    encoding = _encoding(ds)
    with dask.config.set(scheduler="synchronous"):
        if not _time_blocks(ds):
            ds.to_netcdf(tmp, format="NETCDF4", engine="netcdf4", encoding=encoding)
            return
        _to_netcdf_by_time(ds, tmp, encoding)


def _time_blocks(ds: xr.Dataset) -> list[slice]:
    """Return the time blocks of ``ds``'s first lazy variable on ``time`` (none when there is none)."""
    for var in ds.variables.values():
        if var.chunks is not None and "time" in var.dims:
            edges = np.cumsum((0, *var.chunks[var.dims.index("time")]))
            return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    return []


def _to_netcdf_by_time(ds: xr.Dataset, tmp: str | os.PathLike, encoding: dict) -> None:
    """Write ``ds`` as ``to_netcdf`` does, its lazy variables block of time after block of time."""
    import dask.array as da
    from xarray.backends import NetCDF4DataStore
    from xarray.backends.common import ArrayWriter

    store = NetCDF4DataStore.open(tmp, mode="w", format="NETCDF4")
    try:
        writer = ArrayWriter()
        ds.dump_to_store(store, writer=writer, encoding=encoding)  # the layout and the in-memory values
        lazy = [(str(t.variable_name), s, t) for s, t in zip(writer.sources, writer.targets, strict=True)]
        for name, source, _ in lazy:
            # the library caches every chunk written (16 MiB a variable) until the file is closed:
            # room for two chunks, full ones evicted first, keeps one block in memory
            chunk = max(1, int(np.prod([max(c) for c in source.chunks]))) * source.dtype.itemsize
            store.ds.variables[name].set_var_chunk_cache(size=2 * chunk, preemption=1.0)
        for k, block in enumerate(_time_blocks(ds)):
            sources, targets, regions = [], [], []
            for name, source, target in lazy:
                dims = ds.variables[name].dims
                if "time" not in dims and k:
                    continue  # written whole with the first block
                region = tuple(block if d == "time" else slice(None) for d in dims)
                sources.append(source[region])
                targets.append(target)
                regions.append(region)
            da.store(sources, targets, regions=regions, lock=writer.lock, compute=True)
    finally:
        store.close()


def write_into(ds: xr.Dataset, tmp: str | os.PathLike, *, target: str | os.PathLike,
               validate: bool = True) -> None:
    """Write ``ds`` as :func:`write_artefact` would, into the temporary ``tmp`` of ``target``.

    For writers that finish the file before publishing it (the certificate's seal): ``tmp``
    comes from :func:`atomic_path` for ``target``, which publishes it.  Messages name ``target``.
    """
    ds = _ready(ds, target, validate=validate)
    _to_netcdf(ds, tmp)


def _ready(ds: xr.Dataset, path: str | os.PathLike, *, validate: bool) -> xr.Dataset:
    # open_artefact's in-memory notes on where a dataset was read from describe that file,
    # not this one: never persist them
    ds = ds.copy(deep=False)
    ds.attrs = {k: v for k, v in ds.attrs.items() if not k.startswith("lidarcal_source_")}
    if validate:
        validate_dataset(ds, source=str(path), raise_on_error=True)
    problems = text_problems(ds)  # whatever the entry points let through: never written
    if problems:
        raise ValidationError(problems, source=str(path))
    return _cf_ready(ds)


def _bounds_names(ds: xr.Dataset) -> list[str]:
    return [str(v.attrs["bounds"]) for v in ds.variables.values()
            if str(v.attrs.get("bounds", "")) in ds.variables]


def _cf_ready(ds: xr.Dataset) -> xr.Dataset:
    """Attribute-only CF details settled at write time (values are never touched).

    * Bounds variables are written as plain variables: xarray would otherwise list a
      coordinate no data variable uses in a global ``coordinates`` attribute, which CF does not
      define.  :func:`open_artefact` makes them coordinates again.
    * Times get ``units_metadata = "leap_seconds: none"`` (CF 1.11 §4.4.1): numpy datetimes
      count no leap seconds (:func:`open_artefact` drops it again: it describes the encoding).
    * ACDD ties ``time_coverage_start``/``_end`` to a time variable; an artefact without one
      (a bench cube: the period of the bench run) stores them as ``source_time_coverage_*``,
      and :func:`open_artefact` gives them their ACDD names back.
    """
    out = ds.reset_coords([n for n in _bounds_names(ds) if n in ds.coords and n not in ds.dims])
    for var in out.variables.values():
        if var.dtype.kind == "M" and "units_metadata" not in var.attrs:
            var.attrs = {**var.attrs, "units_metadata": "leap_seconds: none"}
    if not _has_time(out):
        out.attrs = {(f"source_{k}" if k in _COVERAGE else k): v for k, v in out.attrs.items()}
    return out


_COVERAGE = ("time_coverage_start", "time_coverage_end")


def _has_time(ds: xr.Dataset) -> bool:
    return any(v.dtype.kind == "M" and v.ndim == 1 for v in ds.variables.values())


def open_artefact(
    path: str | os.PathLike,
    kind: str | None = None,
    *,
    chunks: dict | None = None,
    load: bool = True,
    image: bytes | None = None,
) -> xr.Dataset:
    """Open a lidarcal artefact (or input file) with clear errors.

    The file's SHA-256 and name are attached as ``lidarcal_source_sha256`` and
    ``lidarcal_source_file`` so that downstream artefacts can record their inputs.  With
    ``image`` (the file's bytes, :func:`read_image`) the dataset is read from that copy in
    memory, never from the file on disk (:func:`open_image` says why).
    """
    path = check_input_file(path, "netCDF file")
    if (len(image) if image is not None else path.stat().st_size) == 0:
        raise InputError(f"{path}: file is empty")
    try:
        if image is None:
            ds = xr.open_dataset(path, engine="netcdf4", chunks=chunks)
        else:
            ds = xr.open_dataset(xr.backends.NetCDF4DataStore(open_image(path, image)), chunks=chunks)
        if load and chunks is None:
            ds = ds.load()
            ds.close()
    except Exception as exc:
        raise InputError(f"{path}: not a readable netCDF file (truncated or corrupt?): {exc}") from None
    if not ds.variables:
        raise InputError(f"{path}: netCDF file contains no variables (truncated or not a dataset)")
    found = read_attr(ds, "lidarcal_artefact")
    if kind is not None and found is not None and found != kind:
        raise InputError(f"{path}: is a {found!r} artefact; expected a {kind!r} artefact")
    ds = ds.set_coords([n for n in _bounds_names(ds) if n not in ds.coords])  # see _cf_ready
    for var in ds.variables.values():
        if var.dtype.kind == "M" and var.attrs.get("units_metadata") == "leap_seconds: none":
            var.attrs = {k: v for k, v in var.attrs.items() if k != "units_metadata"}
    if not _has_time(ds):
        ds.attrs = {(k[len("source_"):] if k[len("source_"):] in _COVERAGE and k.startswith("source_")
                     and k[len("source_"):] not in ds.attrs else k): v for k, v in ds.attrs.items()}
    ds.attrs["lidarcal_source_sha256"] = sha256(path) if image is None else hashlib.sha256(image).hexdigest()
    ds.attrs["lidarcal_source_file"] = path.name
    if image is not None:
        ds.encoding["source"] = str(path)
    return ds


def read_image(path: str | os.PathLike, what: str = "netCDF file") -> bytes:
    """Return the bytes of the input ``path`` (refused as :func:`check_input_file` does), for an image.

    Raises
    ------
    InputError
        If ``path`` is missing, not a regular file or unreadable.
    """
    path = check_input_file(path, what)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: {what} cannot be read ({exc.strerror})") from None


def open_image(path: str | os.PathLike, image: bytes):
    """Open the bytes ``image`` of the netCDF file ``path`` as a ``netCDF4.Dataset`` held in memory.

    netCDF-C/HDF5 share one file object among every open of the same file in a process; a
    variable-length string read through a second open of a file, while a first one stays open
    (a Dataset the caller still holds, xarray's cached handle), corrupts that shared object,
    and a later open of the file dies with SIGSEGV.  An image in memory under a name of its
    own is a file of its own: whatever the caller has open, reading it never touches theirs.
    It is also exactly the bytes checked, however the file on disk changes meanwhile.

    Raises
    ------
    InputError
        If ``image`` is not a netCDF file.
    """
    import netCDF4

    try:
        return netCDF4.Dataset(f"{os.fspath(path)}#memory-{uuid.uuid4().hex}", mode="r", memory=image)
    except OSError as exc:
        raise InputError(f"{path}: not a readable netCDF file: {exc}") from None
