"""Regenerate src/freqbrdf/data/lobe_width.csv, the GGX lobe's spread in the plane of incidence and
across it relative to normal incidence (`freqbrdf.estimate.lobe_spread`; first block of rows:
along the plane, second: across it; rows: cos theta_o from 0 to 1, columns: roughness from 0 to 1).
The first row (cos theta_o = 0, where the lobe lies below the horizon) repeats its neighbour.

    python scripts/make_lobe_width_table.py      # ~1 min on one core; deterministic
"""

from __future__ import annotations

import numpy as np

from freqbrdf import estimate
from freqbrdf.fileio import atomic_path


def main() -> None:
    cos_nodes, roughness_nodes = estimate.table_nodes()
    table = np.empty((2, len(cos_nodes), len(roughness_nodes)))
    for column, roughness in enumerate(roughness_nodes):
        normal_incidence = estimate.lobe_spread(1.0, roughness)[1]
        for row, cos_theta in enumerate(cos_nodes):
            table[:, row, column] = np.array(estimate.lobe_spread(cos_theta, roughness)) / normal_incidence
    table[:, 0] = table[:, 1]  # exactly grazing the lobe lies below the horizon: no spread to speak of
    path = estimate._WIDTH_TABLE_PATH
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table.reshape(-1, len(roughness_nodes)), fmt="%.4f", delimiter=",")
    print(f"wrote {path} ({2 * len(cos_nodes)} x {len(roughness_nodes)})")


if __name__ == "__main__":
    main()
