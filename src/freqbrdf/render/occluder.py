"""Batched ray tests against a mesh with Mitsuba: what blocks the view of a point.

The observation stage casts a ray from each texel to each camera centre to test visibility, and
optionally towards the environment for self-occlusion (docs/method.md#observations).
"""

from __future__ import annotations

import importlib

import numpy as np

from freqbrdf.render.scenes import mesh_shape, mitsuba, restored_floating_point

# Rays per Mitsuba call: large enough to amortise the fixed cost of a call, small enough to bound
# its transient buffers.
RAYS_PER_BATCH = 1 << 21


class Occluder:
    """A mesh loaded into Mitsuba for batched ray tests (what blocks the view of a point).

    Parameters
    ----------
    mesh : Mesh
        The occluding geometry.
    threads : int, optional
        Threads the rays are traced on (`set_threads`); None: Dr.Jit's own count, every core.
    """

    def __init__(self, mesh, threads: int | None = None):
        self._mitsuba = mitsuba()
        self._drjit = importlib.import_module("drjit")
        if threads is not None:
            self.set_threads(threads)
        with restored_floating_point():
            self._scene = self._mitsuba.load_dict({"type": "scene", "object": mesh_shape(mesh, {"type": "diffuse"})})

    def set_threads(self, threads: int) -> None:
        """Trace on ``threads`` threads: the fit's own (a batch task's CPUs), not every core of a shared machine.

        Parameters
        ----------
        threads : int
            At least 1. Dr.Jit's setting is the process's: it holds for every `Occluder`.
        """
        if self._drjit.thread_count() != threads:
            self._drjit.set_thread_count(threads)

    def hits(self, origins: np.ndarray, directions: np.ndarray, max_distance: np.ndarray | None = None) -> np.ndarray:
        """Test which rays hit the mesh.

        Parameters
        ----------
        origins : (M, 3) array_like
            Ray origins in world space.
        directions : (M, 3) array_like
            Unit ray directions.
        max_distance : (M,) array_like, optional
            How far each ray reaches; None: unbounded.

        Returns
        -------
        (M,) bool
            True where the ray hits the mesh before ``max_distance``.
        """
        return self.hits_rows(np.ascontiguousarray(np.asarray(origins, np.float32).T),
                              np.ascontiguousarray(np.asarray(directions, np.float32).T), max_distance)

    def hits_rows(self, origins: np.ndarray, directions: np.ndarray, max_distance: np.ndarray | None = None
                  ) -> np.ndarray:
        """Test which rays hit the mesh, rays given as rows (what Dr.Jit takes without a copy).

        Rays are traced in batches of RAYS_PER_BATCH.

        Parameters
        ----------
        origins : (3, M) float32, C-contiguous
            Ray origins in world space, one row per coordinate.
        directions : (3, M) float32, C-contiguous
            Unit ray directions, one row per coordinate.
        max_distance : (M,) array_like, optional
            How far each ray reaches; None: unbounded.

        Returns
        -------
        (M,) bool
            True where the ray hits the mesh before ``max_distance``.
        """
        hits = np.zeros(origins.shape[1], dtype=bool)
        for rays, ray in self._batches(origins, directions, max_distance):
            hits[rays] = np.asarray(self._scene.ray_test(ray), dtype=bool)
        return hits

    def first_hits_rows(self, origins: np.ndarray, directions: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Find where the rays that meet the mesh first meet it, rays given as rows.

        Rays are traced in batches of RAYS_PER_BATCH.

        Parameters
        ----------
        origins : (3, M) float32, C-contiguous
            Ray origins in world space, one row per coordinate.
        directions : (3, M) float32, C-contiguous
            Unit ray directions, one row per coordinate.

        Returns
        -------
        hit : (H,) int64
            The rays that meet the mesh, ascending.
        distance : (H,) float32
            How far each travels to its first hit.
        face : (H,) int64
            The face it hits (the mesh's face order).
        barycentric : (H, 2) float32
            The hit's weights (b1, b2) of the face's second and third corners (the first has
            1 - b1 - b2).
        """
        dr = self._drjit
        parts = []
        for rays, ray in self._batches(origins, directions):
            found = self._scene.ray_intersect_preliminary(ray)
            dr.eval(found.t, found.prim_index, found.prim_uv)  # one traversal for the three
            distance = np.asarray(found.t, dtype=np.float32)
            hit = np.flatnonzero(np.isfinite(distance))
            index = self._mitsuba.UInt32(hit.astype(np.uint32))
            face = np.asarray(dr.gather(self._mitsuba.UInt32, found.prim_index, index), dtype=np.int64)
            barycentric = np.asarray(dr.gather(self._mitsuba.Point2f, found.prim_uv, index), dtype=np.float32)
            parts.append((hit + rays.start, distance[hit], face, barycentric.reshape(2, -1).T))
        if not parts:
            return np.empty(0, np.int64), np.empty(0, np.float32), np.empty(0, np.int64), np.empty((0, 2), np.float32)
        return tuple(np.concatenate([part[k] for part in parts]) for k in range(4))

    def release_memory(self) -> None:
        """Give back the memory Dr.Jit keeps for the buffers of traced rays (its allocation cache).

        The scene stays loaded; the next trace allocates its buffers again.
        """
        self._drjit.flush_malloc_cache()

    def _batches(self, origins: np.ndarray, directions: np.ndarray, max_distance: np.ndarray | None = None):
        """Yield (slice, Mitsuba Ray3f) per batch of RAYS_PER_BATCH rays given as rows, in Mitsuba's floating point."""
        mi = self._mitsuba
        with restored_floating_point():
            for first in range(0, origins.shape[1], RAYS_PER_BATCH):
                rays = slice(first, first + RAYS_PER_BATCH)
                ray = mi.Ray3f(mi.Point3f(*(mi.Float(row[rays]) for row in origins)),
                               mi.Vector3f(*(mi.Float(row[rays]) for row in directions)))
                if max_distance is not None:
                    ray.maxt = mi.Float(np.asarray(max_distance, np.float32)[rays])
                yield rays, ray
