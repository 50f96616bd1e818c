"""Regenerate src/freqbrdf/data/lobe_tilt.csv, the split-sum light lookup's tilt per node and lobe
term (`freqbrdf.estimate.fit_lobe_tilt`; one block of rows per term of `estimate.LOBE_TERMS`, rows:
cos theta_o from 0 to 1, columns: roughness from 0 to 1).

    python scripts/make_lobe_tilt_table.py      # ~1 min on one core; deterministic

At normal incidence (the last row of a block) every tilt looks up the normal; the row repeats its
neighbour so that interpolation towards it stays smooth.
"""

from __future__ import annotations

import numpy as np

from freqbrdf import estimate
from freqbrdf.fileio import atomic_path


def main() -> None:
    cos_nodes, roughness_nodes = estimate.lobe_tilt_nodes()
    blocks = []
    for term in estimate.LOBE_TERMS:
        block = np.array([[estimate.fit_lobe_tilt(mu, r, term) for r in roughness_nodes] for mu in cos_nodes])
        block[-1] = block[-2]
        blocks.append(block)
    table = np.concatenate(blocks)
    path = estimate._TILT_TABLE_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt="%.4f", delimiter=",")
    print(f"wrote {path} ({table.shape[0]} x {table.shape[1]})")


if __name__ == "__main__":
    main()
