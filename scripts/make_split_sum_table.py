"""Regenerate src/freqbrdf/model/data/split_sum.csv, the GGX lobe's directional albedo terms A, B and E
(`freqbrdf.model.tables.integrate_split_sum_table`; three blocks of rows, one per term; rows: cos
theta_o from 0 to 1, columns: roughness from 0 to 1), every digit kept so that the loaded table
equals the integrated one.

    python scripts/make_split_sum_table.py      # deterministic
"""

from __future__ import annotations

import numpy as np

from freqbrdf.fileio import atomic_path
from freqbrdf.model import tables


def main() -> None:
    table = tables.integrate_split_sum_table()
    path = tables.SPLIT_SUM_TABLE_PATH
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table.reshape(-1, table.shape[2]), fmt="%.17g", delimiter=",")
    print(f"wrote {path} ({table.shape[0] * table.shape[1]} x {table.shape[2]})")


if __name__ == "__main__":
    main()
