"""Locate the embedded sample data (shipped in the wheel, or the checkout's folder)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["sample_data_dir", "sample_file"]


def sample_data_dir() -> Path:
    """Directory holding lidarcal's embedded sample inputs."""
    packaged = resources.files("lidarcal") / "sample_data"
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(str(resources.files("lidarcal"))).parent / "sample_data"


def sample_file(name: str) -> Path:
    """Path of one embedded sample file; raises FileNotFoundError naming what exists."""
    path = sample_data_dir() / name
    if not path.exists():
        have = sorted(p.name for p in sample_data_dir().iterdir())
        raise FileNotFoundError(f"sample file {name!r} not found in {sample_data_dir()}; have {have}")
    return path
