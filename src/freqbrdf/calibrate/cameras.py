"""Each photograph's pose, refined against its mask's silhouette.

docs/method.md#calibration (M17). Poses from structure-from-motion carry residual error: a camera
turned half a degree puts every sample a few pixels from where the fit looks for it. The mesh's
outline in a photograph must fall on the edge of that photograph's mask. The outline's points are
the mesh's contour edges (between a face turned to the camera and one turned away, or on an open
border) that lie on the edge of the projected mesh; each camera's small turn (about its centre)
and shift is found by Gauss-Newton on those points' signed distance to the mask's edge, with a
Huber weight against points the mask disagrees with and a prior that keeps what the outline does
not determine (a sphere's turn about its own centre) where the capture put it.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numba
import numpy as np
from scipy import ndimage

from freqbrdf.calibrate._kernels import covered_points
from freqbrdf.calibrate.probe import rotation_about
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.mesh import Mesh

__all__ = ["CameraRefinement", "MeshOutline", "refine_cameras"]

# Where along each contour edge its points lie (fractions of the edge).
CONTOUR_SAMPLES = (0.25, 0.5, 0.75)
# A contour point lies on the outline where no face covers the point this far outside it in the image.
OUTSIDE_PX = 0.25
# Contour points this close to the image border are left out (the mask's edge there is the frame's).
BORDER_PX = 2.0
# Residuals beyond this many pixels weigh less (Huber).
HUBER_PX = 0.1
# The prior on a camera's correction (its turn in radians, its shift as a share of its distance to
# the object): this share of the outline's largest information (the normal matrix's largest
# eigenvalue at the given pose). Motions the outline does not see (a sphere turned about its
# centre) carry a few 1e-5 of it and stay where the capture put them; the weakest a real object's
# outline sees carry about 1e-3 (benchmarks/studies/calibration.py).
PRIOR_SHARE = 2e-4
ITERATIONS = 15
# Iterations at which the outline's points are found again (between them the same points are
# projected: the outline moves little with a small correction).
RESELECT = (0, 1, 3, 6, 10)
# A refined pose is kept where its outline's distance to the mask's edge is this many times smaller
# than the given pose's; else the given pose is (the mask's own noise moves a camera too).
SIGNIFICANT_RATIO = 1.25
CONVERGED_RAD = 1e-4
# A mask whose edge lies this many pixels or more off the mesh's outline at the given pose (median:
# a segmentation's halo or erosion) has that offset estimated with the pose, so that the pose does
# not move to take it; closer, the mask is taken as drawn on the outline.
MASK_OFFSET_PX = 0.5
# Fewer outline points than this refine nothing.
MIN_POINTS = 24
# A view whose outline lies farther than this from its mask's edge after refinement (robust std,
# pixels) is one refinement did not recover.
BAD_OUTLINE_PX = 1.5


@dataclass
class CameraRefinement:
    """What `refine_cameras` found, per view.

    Attributes
    ----------
    cameras : list of Camera
        The cameras refined (the given ones where not refined).
    turn_deg : (V,) float64
        Angle of each camera's correction, degrees.
    shift : (V,) float64
        Length of each camera's move, as a share of its distance to the object.
    outline_before_px, outline_after_px : (V,) float64
        Robust std of the outline's distance to the mask's edge before and after, pixels; NaN where
        not refined.
    refined : (V,) bool
        Views with a mask and enough outline to refine.
    mask_offset_px : (V,) float64
        How far each mask's edge lies outside the mesh's outline, pixels (a segmentation's halo;
        negative: inside); 0 where closer than `MASK_OFFSET_PX`.
    """

    cameras: list[Camera]
    turn_deg: np.ndarray
    shift: np.ndarray
    outline_before_px: np.ndarray
    outline_after_px: np.ndarray
    refined: np.ndarray
    mask_offset_px: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def median_mask_offset_px(self) -> float:
        """The median of ``mask_offset_px`` over the refined views (0 where none is)."""
        offsets = self.mask_offset_px[self.refined] if self.mask_offset_px.size else np.zeros(0)
        return float(np.median(offsets)) if offsets.size else 0.0

    @property
    def bad_views(self) -> np.ndarray:
        """(K,) int: views whose outline still misses the mask's edge by more than `BAD_OUTLINE_PX`."""
        return np.flatnonzero(self.refined & (self.outline_after_px > BAD_OUTLINE_PX))

    def to_dict(self) -> dict:
        """Give the refinement as plain data, as summary.json records it.

        Returns
        -------
        dict
            Per view: ``turn_deg``, ``shift`` (share of distance), ``outline_before_px``,
            ``outline_after_px`` (None where not refined), ``refined``, ``mask_offset_px``;
            ``bad_views``.
        """
        def listed(values):
            return [None if not np.isfinite(value) else float(value) for value in values]

        return {"turn_deg": listed(self.turn_deg), "shift": listed(self.shift),
                "outline_before_px": listed(self.outline_before_px),
                "outline_after_px": listed(self.outline_after_px),
                "refined": self.refined.tolist(), "mask_offset_px": listed(self.mask_offset_px),
                "bad_views": self.bad_views.tolist()}


@dataclass(frozen=True)
class MeshOutline:
    """A mesh's edges with the faces either side, for its contour from any camera.

    Attributes
    ----------
    vertices : (n, 3) float64
        Positions, welded (a UV seam's copies are one vertex).
    faces : (F, 3) int64
        Faces over the welded vertices.
    edge_start, edge_end : (E, 3) float64
        Each edge's end points.
    face_left, face_right : (E,) int64
        The faces either side; ``face_right`` is -1 on an open border (or a non-manifold edge).
    opposite_left, opposite_right : (E, 3) float64
        The corner of each of those faces off the edge (the left one's on a border).
    face_centre, face_normal : (F, 3) float64
        Each face's centroid and (unnormalised) normal.
    centre : (3,) float64
        The middle of the mesh's bounding box.
    """

    vertices: np.ndarray
    faces: np.ndarray
    edge_start: np.ndarray
    edge_end: np.ndarray
    face_left: np.ndarray
    face_right: np.ndarray
    opposite_left: np.ndarray
    opposite_right: np.ndarray
    face_centre: np.ndarray
    face_normal: np.ndarray
    centre: np.ndarray

    @classmethod
    def of(cls, mesh: Mesh) -> MeshOutline:
        """Build the outline's edges of ``mesh``."""
        vertices, welded = np.unique(np.asarray(mesh.vertices, np.float64), axis=0, return_inverse=True)
        faces = welded.reshape(-1)[np.asarray(mesh.faces)].astype(np.int64)
        corners = vertices[faces]
        pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        opposite = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
        owner = np.tile(np.arange(len(faces)), 3)
        pairs.sort(axis=1)
        key = pairs[:, 0] * len(vertices) + pairs[:, 1]
        order = np.argsort(key, kind="stable")
        key, pairs, owner, opposite = key[order], pairs[order], owner[order], opposite[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        counts = np.diff(np.r_[starts, len(key)])
        two = counts == 2
        second = np.where(two, starts + 1, starts)
        return cls(vertices=vertices, faces=faces, edge_start=vertices[pairs[starts, 0]],
                   edge_end=vertices[pairs[starts, 1]], face_left=owner[starts],
                   face_right=np.where(two, owner[second], -1), opposite_left=vertices[opposite[starts]],
                   opposite_right=vertices[opposite[second]], face_centre=corners.mean(axis=1),
                   face_normal=np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                   centre=0.5 * (vertices.min(axis=0) + vertices.max(axis=0)))

    def contour(self, eye: np.ndarray) -> tuple[np.ndarray, ...]:
        """Return points on the contour edges seen from ``eye``.

        Parameters
        ----------
        eye : (3,) float64
            The camera's centre.

        Returns
        -------
        points : (M, 3) float64
            `CONTOUR_SAMPLES` points along each edge between a face turned to ``eye`` and one
            turned away, and along each open border.
        start, end : (M, 3) float64
            The end points of each point's edge.
        inner : (M, 3) float64
            The corner off the edge of the face turned to ``eye`` (the border's face): the side
            of the edge the mesh lies on in the image.
        faces : (M, 2) int64
            The faces either side of each point's edge (-1 for none).
        facing : (F,) bool
            The faces turned to ``eye``.
        """
        facing = np.einsum("ij,ij->i", eye - self.face_centre, self.face_normal) > 0.0
        border = self.face_right < 0
        right = np.maximum(self.face_right, 0)
        edges = np.flatnonzero(border | (facing[self.face_left] != facing[right]))
        use_left = (facing[self.face_left] | border)[edges]
        inner = np.where(use_left[:, None], self.opposite_left[edges], self.opposite_right[edges])
        start, end = self.edge_start[edges], self.edge_end[edges]
        repeat = len(CONTOUR_SAMPLES)
        points = np.concatenate([start + t * (end - start) for t in CONTOUR_SAMPLES])
        faces = np.stack([self.face_left[edges], self.face_right[edges]], axis=1)
        return (points, np.tile(start, (repeat, 1)), np.tile(end, (repeat, 1)), np.tile(inner, (repeat, 1)),
                np.tile(faces, (repeat, 1)), facing)

    def on_outline(self, camera: Camera, pixels: np.ndarray, start: np.ndarray, end: np.ndarray,
                   inner: np.ndarray, faces: np.ndarray, facing: np.ndarray) -> np.ndarray:
        """Return (M,) bool: the contour points (at ``pixels``) with nothing of the mesh just outside them.

        A point `OUTSIDE_PX` away from its edge's image, on the side away from its face, is
        tested against every projected face turned to the camera but the edge's own (on a closed
        mesh what a face turned away covers, one turned to it covers too): covered, the contour
        lies in front of more of the mesh (or behind it), not on the outline.
        """
        edge = camera.project(end)[0] - camera.project(start)[0]
        normal = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        towards_inner = np.einsum("ij,ij->i", normal, camera.project(inner)[0] - pixels)
        normal[towards_inner > 0] *= -1.0
        vertex_pixels, depth = camera.project(self.vertices)
        queries = np.ascontiguousarray(pixels + OUTSIDE_PX * normal)
        used = facing | (self.face_right < 0).any()  # an open mesh's faces turned away may be all there is
        covered = covered_points(queries, np.ascontiguousarray(faces), np.nan_to_num(vertex_pixels), depth > 0,
                                 self.faces, used, camera.height, camera.width)
        return ~covered & np.isfinite(normal).all(axis=1)


def signed_distance(coverage: np.ndarray) -> np.ndarray:
    """Return each pixel centre's signed distance to a mask's edge, positive outside, in pixels.

    Parameters
    ----------
    coverage : (H, W) float or bool
        The share of each pixel the object covers; on an anti-aliased mask's edge pixels the
        distance is 0.5 - coverage, which places the edge within the pixel.

    Returns
    -------
    (H, W) float64
        The distances; all inf where the mask is empty or full (no edge).
    """
    coverage = np.asarray(coverage, np.float64)
    mask = coverage > 0.5
    if mask.all() or not mask.any():
        return np.full(mask.shape, np.inf)
    outside = ndimage.distance_transform_edt(~mask)
    inside = ndimage.distance_transform_edt(mask)
    distance = np.where(mask, 0.5 - inside, outside - 0.5)
    edge = np.abs(distance) == 0.5
    distance[edge] = 0.5 - coverage[edge]
    return distance


def _sample(grid: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Sample ``grid`` (H, W) bilinearly at ``pixels`` (M, 2) x, y (a pixel's centre at index + 0.5)."""
    return ndimage.map_coordinates(grid, [pixels[:, 1] - 0.5, pixels[:, 0] - 0.5], order=1, mode="nearest")


def _robust_std(residual: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(residual))) if residual.size else float("nan")


def _skew(vectors: np.ndarray) -> np.ndarray:
    """(M, 3, 3) cross-product matrices of (M, 3) vectors."""
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], 1)


class _ViewFit:
    """One view's outline residuals and their derivatives with respect to the camera's correction."""

    def __init__(self, outline: MeshOutline, coverage: np.ndarray):
        self.outline = outline
        self.distance = signed_distance(coverage)
        # A mask without an edge (empty or full) has no gradient: `refine_camera` leaves its view as given.
        rows, cols = np.gradient(self.distance) if np.isfinite(self.distance).all() else (self.distance, self.distance)
        self.gradient = (cols, rows)

    def outline_points(self, camera: Camera) -> np.ndarray:
        """Return (M, 3) the mesh's points on its outline from ``camera`` (not near the image's border)."""
        points, start, end, inner, faces, facing = self.outline.contour(camera.center)
        pixels, depth = camera.project(points)
        keep = (depth > 0) & np.all(np.isfinite(pixels), axis=1)
        keep &= (pixels[:, 0] > BORDER_PX) & (pixels[:, 0] < camera.width - BORDER_PX)
        keep &= (pixels[:, 1] > BORDER_PX) & (pixels[:, 1] < camera.height - BORDER_PX)
        on_outline = self.outline.on_outline(camera, pixels[keep], start[keep], end[keep], inner[keep], faces[keep],
                                             facing)
        return points[keep][on_outline]

    def residuals(self, camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the pixels (M, 2) of the outline's ``points`` (M, 3) and their signed distances (M,) to the mask's edge."""
        pixels, _ = camera.project(points)
        return pixels, _sample(self.distance, np.nan_to_num(pixels))

    def jacobian(self, camera: Camera, points: np.ndarray, pixels: np.ndarray, distance: float) -> np.ndarray:
        """(M, 6): the residuals' derivatives by the camera's turn (world axes, radians) and shift (/ distance)."""
        rotation, centre = camera.camera_to_world[:3, :3], camera.camera_to_world[:3, 3]
        local = (points - centre) @ rotation
        depth = -local[:, 2]
        d_pixel = np.zeros((len(points), 2, 3))  # d(x, y) / d(camera-space point)
        d_pixel[:, 0, 0] = camera.fx / depth
        d_pixel[:, 0, 2] = camera.fx * local[:, 0] / depth ** 2
        d_pixel[:, 1, 1] = -camera.fy / depth
        d_pixel[:, 1, 2] = -camera.fy * local[:, 1] / depth ** 2
        gradient = np.stack([_sample(self.gradient[0], pixels), _sample(self.gradient[1], pixels)], axis=1)
        d_local = np.einsum("mi,mij->mj", gradient, d_pixel)  # (M, 3)
        # q = R^T (p - c): a world turn w about c moves it by R^T [p - c]x w, a shift s * distance by -R^T s.
        d_turn = np.einsum("mj,mjk->mk", d_local @ rotation.T, _skew(points - centre))
        d_shift = -distance * (d_local @ rotation.T)
        return np.concatenate([d_turn, d_shift], axis=1)


def _moved(camera: Camera, turn: np.ndarray, shift: np.ndarray) -> Camera:
    """Return ``camera`` turned by ``turn`` (world axis-angle, about its centre) and moved by ``shift``."""
    matrix = camera.camera_to_world.copy()
    angle = float(np.linalg.norm(turn))
    if angle > 0.0:
        matrix[:3, :3] = rotation_about(turn / angle, angle) @ matrix[:3, :3]
    matrix[:3, 3] += shift
    return replace(camera, camera_to_world=matrix)


def refine_camera(outline: MeshOutline, camera: Camera, coverage: np.ndarray) -> tuple[Camera, float, float, float]:
    """Refine one camera's pose so that the mesh's outline falls on its mask's edge.

    Parameters
    ----------
    outline : MeshOutline
        The mesh's edges.
    camera : Camera
        The pose as given.
    coverage : (H, W) float or bool
        The object's mask in that camera's photograph (`signed_distance`).

    Returns
    -------
    camera : Camera
        The pose refined; the given one where the outline has fewer than `MIN_POINTS` points or
        refining does not bring it `SIGNIFICANT_RATIO` times closer to the mask's edge.
    before, after : float
        Robust std of the outline's distance to the mask's edge before and after, pixels (NaN
        where not refined).
    mask_offset : float
        How far the mask's edge lies outside the outline, pixels (negative: inside; 0 where it is
        closer than `MASK_OFFSET_PX` at the given pose).
    """
    view = _ViewFit(outline, coverage)
    if not np.isfinite(view.distance).all():
        return camera, float("nan"), float("nan"), 0.0
    distance = float(np.linalg.norm(camera.center - outline.centre))
    prior = None
    # The total turn, shift (as a share of distance) and the mask's edge offset so far: a mask drawn
    # wider or narrower than the object (a segmentation's halo or erosion) lies a constant distance
    # off its outline, which the offset takes instead of the pose.
    correction = np.zeros(7)
    given, before = camera, float("nan")
    moved = 0.0  # the largest step since the points were found (turn, or shift as a share of distance)
    for iteration in range(ITERATIONS):
        if iteration in RESELECT:
            points, moved = view.outline_points(camera), 0.0
        pixels, residual = view.residuals(camera, points)
        if len(residual) < MIN_POINTS:
            return given, float("nan"), float("nan"), 0.0
        if iteration == 0:
            # A mask off the outline by MASK_OFFSET_PX or more at the given pose has its offset
            # estimated with the pose; a closer one is taken as drawn on the outline.
            free_offset = abs(float(np.median(residual))) >= MASK_OFFSET_PX
            correction[6] = -float(np.median(residual)) if free_offset else 0.0
            offset = float(correction[6])
            before = _robust_std(residual + correction[6])
        residual = residual + correction[6]
        weight = 1.0 / np.sqrt(residual ** 2 + HUBER_PX ** 2)
        jacobian = np.concatenate([view.jacobian(camera, points, pixels, distance),
                                   np.full((len(points), 1), 1.0 if free_offset else 0.0)], axis=1)
        normal = jacobian.T @ (weight[:, None] * jacobian)
        if prior is None:  # on the pose; the offset is free (or held at 0)
            prior = np.zeros((7, 7))
            prior[:6, :6] = PRIOR_SHARE * np.linalg.eigvalsh(normal[:6, :6])[-1] * np.eye(6)
            prior[6, 6] = 0.0 if free_offset else 1.0
        normal = normal + prior
        # The prior pulls the total correction, not each step, towards the given pose.
        step = -np.linalg.solve(normal, jacobian.T @ (weight * residual) + prior @ correction)
        correction += step
        camera = _moved(camera, step[:3], distance * step[3:6])
        moved = max(moved, float(np.abs(step[:6]).max()))
        if np.abs(step[:3]).max() < CONVERGED_RAD and np.abs(step[3:6]).max() < CONVERGED_RAD:
            break
    if moved >= CONVERGED_RAD:  # else the outline is the one last found: the pose has barely moved since
        points = view.outline_points(camera)
    after = _robust_std(view.residuals(camera, points)[1] + correction[6])
    if not after < before / SIGNIFICANT_RATIO:
        return given, before, before, offset  # the outline fits no better than as given: the camera is kept
    return camera, before, after, float(correction[6])


def refine_cameras(mesh: Mesh, cameras: list[Camera], masks) -> CameraRefinement:
    """Refine every camera's pose against its mask's silhouette.

    Parameters
    ----------
    mesh : Mesh
        The object.
    cameras : list of V Camera
        The poses as given.
    masks : iterable of V (H, W) float or bool
        Each photograph's object mask as coverage (`signed_distance`); all 1 where a photograph
        has none: not refined.

    Returns
    -------
    CameraRefinement
        The refined cameras and what moved.
    """
    outline = MeshOutline.of(mesh)
    refined_cameras, turn, shift, before, after = [], [], [], [], []
    # Views are independent: refined on threads (numpy and the kernel release the GIL), collected in order.
    with ThreadPoolExecutor(max_workers=numba.config.NUMBA_NUM_THREADS) as pool:
        found = list(pool.map(lambda pair: refine_camera(outline, *pair), zip(cameras, masks)))
    offsets = [offset for *_, offset in found]
    for camera, (refined, outline_before, outline_after, _) in zip(cameras, found):
        relative = refined.camera_to_world[:3, :3] @ camera.camera_to_world[:3, :3].T
        skew = relative - relative.T
        sine = 0.5 * np.linalg.norm([skew[2, 1], skew[0, 2], skew[1, 0]])
        angle = np.degrees(np.arctan2(sine, 0.5 * (np.trace(relative) - 1.0)))
        refined_cameras.append(refined)
        turn.append(angle)
        shift.append(np.linalg.norm(refined.center - camera.center) / np.linalg.norm(camera.center - outline.centre))
        before.append(outline_before)
        after.append(outline_after)
    after_array = np.array(after, np.float64)
    return CameraRefinement(refined_cameras, np.array(turn), np.array(shift), np.array(before, np.float64),
                            after_array, np.isfinite(after_array), np.array(offsets, np.float64))
