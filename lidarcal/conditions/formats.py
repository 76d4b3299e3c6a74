r"""Lidar ten-minute statistics files: one registry of formats, one seam for every reader.

Every command that reads real lidar files (``conditions from-sta``, ``field from-sta``,
``smc``) goes through :func:`read_lidar_files`.  A format is one :class:`LidarFormat` entry of
:data:`FORMATS` (in the spirit of xarray's backends: a name, how to recognise a file, how to
read files), so a further lidar format is one module that parses its files and one entry here,
not edits in every command.  WindCube ``.sta`` files (:mod:`lidarcal.conditions.stafile`, both
dialects) are the first entry.

What a format's reader returns: a list of :class:`~lidarcal.conditions.stafile.StaFile`
records, one per file, checked to belong together (one lidar, one configuration, whole
10-minute periods, no repeated interval): the file's path and SHA-256, its dialect and header,
the lidar's serial (``ID System``), the altitudes, the cone angle and where it came from, the
interval ends and the five per-height quantities (speed, dispersion, direction, CNR,
availability) on (row, altitude).  :mod:`lidarcal.conditions.sta` turns them into
``conditions``.

>>> sorted(FORMATS)
['windcube_sta']
>>> FORMATS["windcube_sta"].recognise(b"HeaderSize=41\r\nVersion=2.1")
True
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from lidarcal.conditions.stafile import StaFile, read_sta_files
from lidarcal.errors import InputError
from lidarcal.io import check_input_file

__all__ = ["LidarFormat", "FORMATS", "format_of", "read_lidar_files"]


@dataclass(frozen=True)
class LidarFormat:
    """One lidar file format: how to recognise its files and how to read them."""

    name: str  #: registry key, recorded in the artefacts read from it
    description: str  #: one line for messages and docs
    suffixes: tuple[str, ...]  #: file-name suffixes (lower case) its files usually have
    #: True when the first bytes of a file (at most :data:`HEAD_BYTES`) are this format's
    recognise: Callable[[bytes], bool]
    #: ``read(paths, *, allow_gaps, cone_angle, cone_angle_from) -> list[StaFile]``, joined-checked
    read: Callable[..., list[StaFile]]


#: How many leading bytes :func:`format_of` reads to recognise a format.
HEAD_BYTES = 256

_STA_FIRST_LINE = re.compile(rb"^\s*(HeaderSize|HeaderLength)\s*=\s*\d+\s*$")


def _is_sta(head: bytes) -> bool:
    """Tell a WindCube ``.sta`` file: its first line is ``HeaderSize=N`` or ``HeaderLength=N``."""
    return bool(_STA_FIRST_LINE.match(head.split(b"\n", 1)[0].rstrip(b"\r")))


#: The formats lidarcal reads, by name.  A new format: a module of its own with a reader
#: returning :class:`~lidarcal.conditions.stafile.StaFile` records, and one entry here.
FORMATS: dict[str, LidarFormat] = {
    "windcube_sta": LidarFormat(
        name="windcube_sta",
        description="WindCube 10-minute statistics (.sta; HeaderSize/Timestamp and HeaderLength/Date "
                    "dialects)",
        suffixes=(".sta", ".stdsta"),
        recognise=_is_sta,
        read=read_sta_files,
    ),
}


def format_of(path: str | os.PathLike) -> LidarFormat:
    """Return the format of the lidar file ``path``: recognised from its first bytes, else its suffix.

    A file a format's suffix names but whose content that format does not recognise is given to
    that format's reader, which says what is wrong with it; a file no format claims is refused.
    """
    path = check_input_file(path, "lidar file")
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
    for fmt in FORMATS.values():
        if fmt.recognise(head):
            return fmt
    for fmt in FORMATS.values():
        if path.suffix.lower() in fmt.suffixes:
            return fmt
    known = "; ".join(f"{f.name}: {f.description}" for f in FORMATS.values())
    first = head.split(b"\n", 1)[0][:60].decode("latin-1") if head else "an empty file"
    raise InputError(
        f"{path}: line 1: not a lidar file format lidarcal reads (first line {first!r}); "
        f"expected one of: {known}"
    )


def read_lidar_files(
    paths: Sequence[str | os.PathLike],
    *,
    allow_gaps: bool = False,
    cone_angle: float | None = None,
    cone_angle_from: str = "--cone-angle",
) -> list[StaFile]:
    """Read the 10-minute statistics files of one lidar, whatever their format (one format per call).

    ``allow_gaps`` reads rows cut short as missing periods; ``cone_angle`` (degree from vertical)
    stands for a cone angle the files do not state and must match one they state, and
    ``cone_angle_from`` names where it came from (the option, or the certificate) in messages
    and in the ``lidar_cone_angle_source`` attribute of what is built from the files.

    Raises
    ------
    InputError
        No file, files of several formats, or anything the format's reader refuses (naming
        the file, line and column).
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no lidar file given; expected one or more 10-minute statistics files (.sta)")
    found = {p: format_of(p) for p in paths}
    names = sorted({f.name for f in found.values()})
    if len(names) > 1:
        listed = ", ".join(f"{p} ({f.name})" for p, f in found.items())
        raise InputError(
            f"files of several formats given ({listed}); expected the files of one lidar in one format"
        )
    return found[paths[0]].read(
        paths, allow_gaps=allow_gaps, cone_angle=cone_angle, cone_angle_from=cone_angle_from
    )
