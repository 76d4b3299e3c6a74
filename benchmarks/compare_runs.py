"""Compare the numbers of two run directories: every variable's stored values, by SHA-256.

``python benchmarks/compare_runs.py OLD_DIR NEW_DIR`` opens each ``*.nc`` of OLD_DIR and the
file of the same name in NEW_DIR with plain netCDF4 (no masking or scaling, the bytes as
stored), hashes each variable's values with its dtype and shape, and prints every variable
that differs or is missing; variables only NEW_DIR has are listed, not compared.  Exit status
1 when anything differs.  Used to show that a change to attributes (issue 18: short attributes)
left a default run's numbers bit-identical.
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


def main(old: str, new: str) -> int:
    """Print the differences; return 1 if any value differs or a variable is missing."""
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
    print(f"{compared} variables compared, {bad} differ or are missing")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1], sys.argv[2]))
