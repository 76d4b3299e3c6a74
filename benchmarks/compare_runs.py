"""Compare the numbers of two run directories: every variable's stored values, by SHA-256.

``python benchmarks/compare_runs.py OLD_DIR NEW_DIR`` opens each ``*.nc`` of OLD_DIR and the
file of the same name in NEW_DIR with plain netCDF4 (no masking or scaling, the bytes as
stored), hashes each variable's values with its dtype and shape, and prints every variable
that differs or is missing; variables only NEW_DIR has are listed, not compared.  Exit status
1 when anything differs.  Used to show that a change to attributes (issue 18: short attributes)
left a default run's numbers bit-identical.

``--attrs`` also compares every variable's attributes and the global attributes, except those
that change from run to run by design (creation dates, ids, history, digests and signatures,
the provenance of the inputs' paths): a refactor that moves where metadata is declared (issue
17) shows here that the files it writes say the same.
"""

import hashlib
import sys
from pathlib import Path

import netCDF4
import numpy as np


def digest(values: np.ndarray) -> str:
    """SHA-256 of an array's dtype, shape and values (text joined by NUL)."""
    h = hashlib.sha256(f"{values.dtype} {values.shape}\n".encode())
    if values.dtype.kind == "O":
        h.update("\0".join(map(str, np.ravel(values))).encode())
    else:
        h.update(np.ascontiguousarray(values).tobytes())
    return h.hexdigest()


#: Attributes that differ between two runs of the same inputs by design (not compared).
VOLATILE = ("date_created", "date_modified", "date_issued", "date_metadata_modified", "history", "id", "uuid",
            "lidarcal_integrity", "lidarcal_sha256", "lidarcal_bounds_sha256", "lidarcal_signature",
            "lidarcal_inputs", "lidarcal_software", "lidarcal_elapsed_seconds", "source_path", "path",
            "lidarcal_source_sha256", "lidarcal_components", "lidarcal_provenance_chain",
            "lidarcal_integrity_attributes", "simulation_date", "certificate_id")


def _plain(value):
    return np.asarray(value).tolist() if isinstance(value, np.ndarray | np.generic) else value


def _same(x, y) -> bool:
    """Equal values, NaN equal to NaN (a float ``_FillValue`` is NaN)."""
    if isinstance(x, str) or isinstance(y, str) or x is None or y is None:
        return x == y
    x, y = np.asarray(x), np.asarray(y)
    if x.dtype.kind in "fc" or y.dtype.kind in "fc":
        return x.shape == y.shape and np.array_equal(x, y, equal_nan=True)
    return x.shape == y.shape and np.array_equal(x, y)


def _attr_differences(where: str, a: dict, b: dict) -> list[str]:
    keys = [k for k in dict.fromkeys([*a, *b]) if k not in VOLATILE]
    return [f"{where}: attribute {k!r}: {_plain(a.get(k))!r} -> {_plain(b.get(k))!r}" for k in keys
            if not _same(a.get(k), b.get(k))]


def main(old: str, new: str, attrs: bool = False) -> int:
    """Print the differences; return 1 if any value (or, with ``attrs``, attribute) differs."""
    bad = compared = 0
    for path in sorted(Path(old).glob("*.nc")):
        other = Path(new) / path.name
        if not other.exists():
            print(f"{path.name}: missing in {new}")
            bad += 1
            continue
        with netCDF4.Dataset(path) as a, netCDF4.Dataset(other) as b:
            a.set_auto_maskandscale(False)
            b.set_auto_maskandscale(False)
            added = sorted(set(b.variables) - set(a.variables))
            if added:
                print(f"{path.name}: variables only in {new} (not compared): {', '.join(added)}")
            for name in a.variables:
                compared += 1
                if name not in b.variables:
                    print(f"{path.name}: {name} missing in {new}")
                    bad += 1
                elif digest(a[name][...]) != digest(b[name][...]):
                    print(f"{path.name}: {name} differs")
                    bad += 1
                elif attrs:
                    found = _attr_differences(f"{path.name}: {name}", a[name].__dict__, b[name].__dict__)
                    for line in found:
                        print(line)
                    bad += bool(found)
            if attrs:
                found = _attr_differences(f"{path.name} (global)", a.__dict__, b.__dict__)
                for line in found:
                    print(line)
                bad += bool(found)
    print(f"{compared} variables compared, {bad} differ or are missing")
    return 1 if bad else 0


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--attrs"]
    if len(args) != 2:
        sys.exit(__doc__)
    sys.exit(main(*args, attrs="--attrs" in sys.argv[1:]))
