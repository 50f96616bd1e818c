"""Batched ray tests against a mesh with Mitsuba: what blocks the view of a point (METHOD.md §3.2)."""

from __future__ import annotations

import numpy as np

from freqbrdf.render.scenes import mesh_shape, mitsuba, restored_floating_point

# Rays per Mitsuba call: one call costs ~10 ms besides the tracing; 2^21 rays keep its transient
# buffers near 100 MB.
RAYS_PER_BATCH = 1 << 21


class Occluder:
    """A mesh loaded into Mitsuba for batched ray tests (what blocks the view of a point)."""

    def __init__(self, mesh):
        self._mitsuba = mitsuba()
        with restored_floating_point():
            self._scene = self._mitsuba.load_dict({"type": "scene", "object": mesh_shape(mesh, {"type": "diffuse"})})

    def hits(self, origins: np.ndarray, directions: np.ndarray, max_distance: np.ndarray | None = None) -> np.ndarray:
        """(M,) bool: the ray from each origin (M, 3) along its unit direction (M, 3) hits the mesh
        before ``max_distance`` (M,) (None: unbounded)."""
        return self.hits_rows(np.ascontiguousarray(np.asarray(origins, np.float32).T),
                              np.ascontiguousarray(np.asarray(directions, np.float32).T), max_distance)

    def hits_rows(self, origins: np.ndarray, directions: np.ndarray, max_distance: np.ndarray | None = None
                  ) -> np.ndarray:
        """`hits` for origins and directions given as (3, M) float32 rows (what Dr.Jit takes
        without a copy); traced in batches of RAYS_PER_BATCH."""
        mi = self._mitsuba
        hits = np.zeros(origins.shape[1], dtype=bool)
        with restored_floating_point():
            for first in range(0, origins.shape[1], RAYS_PER_BATCH):
                rays = slice(first, first + RAYS_PER_BATCH)
                ray = mi.Ray3f(mi.Point3f(*(mi.Float(row[rays]) for row in origins)),
                               mi.Vector3f(*(mi.Float(row[rays]) for row in directions)))
                if max_distance is not None:
                    ray.maxt = mi.Float(np.asarray(max_distance, np.float32)[rays])
                hits[rays] = np.asarray(self._scene.ray_test(ray), dtype=bool)
        return hits
