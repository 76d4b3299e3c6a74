"""Locate lidarcal's packaged data folders (``sample_data/``, ``schemas/``).

In a wheel they are installed inside the package; in a checkout (editable install) they stay
at the repository's top level, beside ``lidarcal/``.  :func:`packaged_dir` is the one place
that knows both.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["packaged_dir", "sample_data_dir", "sample_file"]


def packaged_dir(name: str) -> Path:
    """Return data folder ``name`` as installed in the wheel, else the checkout's top-level folder."""
    packaged = resources.files("lidarcal") / name
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(str(resources.files("lidarcal"))).parent / name  # editable install / checkout


def sample_data_dir() -> Path:
    """Directory holding lidarcal's embedded sample inputs."""
    return packaged_dir("sample_data")


def sample_file(name: str) -> Path:
    """Path of one embedded sample file; raises FileNotFoundError naming what exists."""
    path = sample_data_dir() / name
    if not path.exists():
        have = sorted(p.name for p in sample_data_dir().iterdir())
        raise FileNotFoundError(f"sample file {name!r} not found in {sample_data_dir()}; have {have}")
    return path
