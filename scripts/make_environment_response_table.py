"""Regenerate src/freqbrdf/model/data/environment_response.csv, the GGX lobe's response to each real SH
(degrees <= 5, m >= 0) per lobe term, roughness node and view cosine
(`freqbrdf.model.tables.environment_response`; rows: one block per term of `tables.LOBE_TERMS`,
inside it one block per roughness node of the environment light, inside it cos theta_o from 0 to 1;
columns: the harmonics, l then m).

    python scripts/make_environment_response_table.py      # deterministic
"""

from __future__ import annotations

import numpy as np

from freqbrdf.fileio import atomic_path
from freqbrdf.model import tables


def main() -> None:
    cos_nodes = np.linspace(0.0, 1.0, tables.TABLE_COS_NODES)
    roughness_nodes = np.linspace(0.0, 1.0, tables.ENVIRONMENT_NODES)
    table = np.array([[[tables.environment_response(mu, r, term) for mu in cos_nodes] for r in roughness_nodes]
                      for term in tables.LOBE_TERMS])
    table = table.reshape(-1, table.shape[-1])
    path = tables.ENVIRONMENT_TABLE_PATH
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt="%.6g", delimiter=",")
    print(f"wrote {path} ({table.shape[0]} x {table.shape[1]})")


if __name__ == "__main__":
    main()
