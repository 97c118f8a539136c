"""Write ``tests/data/daisy_flexible_structure.csv`` from the SLICOT copy of DaISy data set 96-013.

The source is ``flexible_structure_dat.mat`` of the GitHub repository ``SLICOT/SLICOT-SystemIdentification``
(commit ``947f1c5edd3f9455577c3ac3505bdc0caa13e042``): one variable ``flexible_structure_dat``, 8523 x 30
doubles, the two shaker forces then the 28 accelerations of a steel subframe. The file written keeps every
row, both inputs and every other accelerometer (outputs 1, 3, ..., 27 counted from 1, the .mat's columns 2,
4, ..., 28 counted from 0), so that it stays near 1.2 MB; tests/data/README.md says why and what was checked.

Every value of the .mat has 6 significant digits, so ``%.6g`` writes it exactly: the script reads the CSV back
and checks it is bit for bit equal to the columns taken.

Usage::

    python scripts/convert_public_mimo_record.py PATH/TO/flexible_structure_dat.mat [OUT.csv]
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
from scipy.io import loadmat

#: SHA-256 of ``flexible_structure_dat.mat`` at the commit above.
SOURCE_SHA256 = "764312c8d1853f445e4b8ae0e77ecfea162fb122f9a6d36e588797068b8a0d74"
#: Columns of the .mat kept (0-based): the two inputs, then the odd-numbered accelerometers.
KEPT = [0, 1, *range(2, 30, 2)]
#: The header row: ``u1``, ``u2`` and the accelerometers' 1-based DaISy numbers.
NAMES = ["u1", "u2", *(f"y{c - 1}" for c in KEPT[2:])]
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "daisy_flexible_structure.csv"


def convert(source: Path, out: Path) -> np.ndarray:
    """Check the source's digest, write the kept columns to ``out`` and check they read back unchanged.

    Returns
    -------
    ndarray, shape (8523, 16)
        The columns written.
    """
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    if digest != SOURCE_SHA256:
        raise SystemExit(f"{source}: SHA-256 {digest}, expected {SOURCE_SHA256}")
    full = loadmat(source)["flexible_structure_dat"]
    if full.shape != (8523, 30):
        raise SystemExit(f"{source}: expected 8523 x 30 values, found {full.shape}")
    kept = np.ascontiguousarray(full[:, KEPT])
    np.savetxt(out, kept, fmt="%.6g", delimiter=",", header=",".join(NAMES), comments="")
    back = np.loadtxt(out, delimiter=",", skiprows=1)
    if not np.array_equal(back, kept):
        raise SystemExit(f"{out}: the CSV does not read back equal to the .mat's columns")
    return kept


def main(argv: list[str]) -> int:
    if not 1 <= len(argv) <= 2:
        print(__doc__.split("Usage::")[1].strip(), file=sys.stderr)
        return 2
    out = Path(argv[1]) if len(argv) == 2 else DEFAULT_OUT
    kept = convert(Path(argv[0]), out)
    print(f"wrote {out}: {kept.shape[0]} rows, columns {', '.join(NAMES)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
