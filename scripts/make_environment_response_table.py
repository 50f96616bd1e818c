"""Regenerate src/freqbrdf/data/environment_response.csv, the environment light's tilt and
per-degree gains per node and lobe term (`freqbrdf.estimate.fit_environment_response`; rows: one
block per term of `estimate.LOBE_TERMS`, inside it one block per part (the tilt, then the gain of
degrees 0..5), inside it cos theta_o from 0 to 1; columns: roughness from 0 to 1).

    python scripts/make_environment_response_table.py      # ~1 min on one core; deterministic

At normal incidence (the last cos row) every tilt looks up the normal; the row repeats its
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
        fits = [[estimate.fit_environment_response(mu, r, term) for r in roughness_nodes] for mu in cos_nodes]
        parts = np.array([[[tilt, *gains] for tilt, gains in row] for row in fits])  # (cos, roughness, parts)
        parts[-1] = parts[-2]
        blocks.append(np.moveaxis(parts, 2, 0).reshape(-1, len(roughness_nodes)))
    table = np.concatenate(blocks)
    path = estimate._ENVIRONMENT_TABLE_PATH
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt="%.5f", delimiter=",")
    print(f"wrote {path} ({table.shape[0]} x {table.shape[1]})")


if __name__ == "__main__":
    main()
