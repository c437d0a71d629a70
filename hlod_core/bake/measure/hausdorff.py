"""The inner nodes' errors (docs/how-it-works.md#the-error, the MSE): the symmetric Hausdorff distance between a
node's LOD and the original triangles below it, from fixed samples, with pymeshlab
(`get_hausdorff_distance`); and h of the error bound (`measure_to_children`).

Data form: geometry as (positions (k,3) float32 in the bake's file-relative frame, faces (m,3)
int rows into them); every distance is computed in the node's unit frame (meshlab.NodeFrame,
as the decimation) and returned in model units.

The samples (fixed, so the same input always bakes to the same file): every original vertex
against the LOD's surface, and the LOD's vertices plus FACE_SAMPLES points of each LOD face
against the original surface. `measure` evaluates all of them; it is the reference.

Pruned measure (`measure_clustered`): the original triangles are cut once per bake into
`Clusters` of about CLUSTER_FACES nearby faces, each with a bounding sphere; the triangle
inequality bounds what a whole cluster can add to the maximum, and a sample that provably cannot
raise it is not evaluated. Every sample that is evaluated gets the very float `measure` gives it,
so the result is `measure`'s float (tests/test_measure_pruned.py checks it on every inner node of
real bakes). Nodes below PRUNE_FROM_VERTICES original vertices are measured whole.
Why: docs/how-it-works.md#the-pruned-hausdorff-measure
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.arrays import compact, concat_indexed
from ..decimate.meshlab import UNIT_DIAGONAL, NodeFrame

#: Barycentric sample points per LOD face for the LOD -> original direction: centroid, three
#: inner points and the edge midpoints. Fixed, so a bake is reproducible (pymeshlab's own face
#: sampling is Monte Carlo with a varying seed and moved node errors by up to 30% between runs).
FACE_SAMPLES = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6],
                         [1 / 6, 1 / 6, 2 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])

#: The bake measures nodes with at least this many original vertices pruned (`measure_clustered`);
#: below it one call per direction measures every sample (`measure`).
PRUNE_FROM_VERTICES = 20_000
#: Faces per cluster (the last cluster of a leaf may hold fewer). Smaller clusters bound tighter
#: and cost more calls; chosen on the crowd's root and its 220k-triangle nodes.
CLUSTER_FACES = 32
#: Slack on every bound, unit-frame lengths (the frame's diagonal is UNIT_DIAGONAL): pymeshlab
#: works in float32 (relative error about 6e-8), so a sample is skipped only when its bound falls
#: below the running maximum by more than this, and skipping never changes the result.
PRUNE_MARGIN = 1e-5
#: measure_clustered measures the node whole when more than this share of its clusters have a
#: bound above the floor (chosen on the crowd's and the gallery's nodes of 20k to 900k vertices: the
#: pruned measure cost 0.06 to 0.4x the whole one's CPU time where the share was at most 0.42, and
#: 1.2 to 1.5x on the gallery's middle nodes, where it was 1.00).
PRUNE_MAX_SHARE = 0.9
#: measure_clustered, where pruning cannot pay: nodes of fewer original vertices are measured whole
#: (`measure`), larger ones with their vertices as a point set (chosen on the yard's nodes, measured
#: whole against that way: 0.10-0.14 s against 0.13-0.17 s at 56k vertices, one bust; 0.42-0.54 s
#: against 0.19-0.24 s at 227k, four busts; 1.9-2.1 s against 0.9 s at 908k, sixteen).
POINT_SET_FROM_VERTICES = 100_000
#: LOD -> original: when more than this share of the samples can still raise the maximum, they are
#: measured against the node's whole original at once (what `measure` does), not cluster by cluster.
WHOLE_TARGET_SHARE = 0.25
#: First batch of LOD -> original samples measured against the clusters within their reach.
FIRST_SAMPLE_BATCH = 256
#: Rows x clusters of one reach test (float64 matrix, 8 bytes each).
_REACH_BLOCK = 1 << 21
#: Faces per block when the faces' boxes are computed (bounds the temporaries: 36 bytes a face).
_BUILD_BLOCK = 1 << 20
#: Cells per axis of the Morton order within a segment (a leaf holds about target_tris faces).
MORTON_CELLS = 1 << 10


def measure(lod: tuple[np.ndarray, np.ndarray], original: tuple[np.ndarray, np.ndarray]) -> float:
    """Symmetric Hausdorff distance between a LOD and the original triangles below its node, both
    (positions f32, faces) in the same frame: the max of (original vertices -> LOD surface) and
    (LOD vertices and FACE_SAMPLES points -> original surface), model units, every sample
    evaluated. NaN if pymeshlab gives none."""
    import pymeshlab

    frame = NodeFrame.of(np.concatenate([lod[0], original[0]]))
    lod_p = frame.to_local(lod[0])
    original_p = frame.to_local(original[0])
    samples = surface_samples(lod_p, lod[1])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=lod_p, face_matrix=lod[1]))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=original_p, face_matrix=original[1]))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=samples))
    both = [hausdorff_max(ms, sampled=1, target=0, count=original_p.shape[0]),
            hausdorff_max(ms, sampled=2, target=1, count=samples.shape[0])]
    return max(both) / frame.scale if all(np.isfinite(both)) else float("nan")


def measure_to_children(lod: tuple[np.ndarray, np.ndarray], children: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """h(node) of the error bound (schedule.compose_bounds): the symmetric Hausdorff distance
    between a LOD and the union of its children's LODs, all (positions f32, faces) in one frame,
    model units; NaN if pymeshlab gives none. Sampled as `measure` samples (the LOD's vertices and
    FACE_SAMPLES points to the children's surface, the children's vertices to the LOD's), in the
    unit frame of both: where the children are leaves, h is the very float `measure` gives.
    Why: docs/how-it-works.md#the-error-bound"""
    kids_positions, kids_faces = concat_indexed(children)
    return measure(lod, (kids_positions, np.asarray(kids_faces, np.int32)))


def surface_samples(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k + 7m, 3) float64: the vertices (k,3) float64 (unit frame), then the FACE_SAMPLES points of
    each of the m faces, each w0 * a + w1 * b + w2 * c summed in that order (the floats np.einsum
    gave, in half its time)."""
    positions = np.asarray(positions, np.float64)
    k = positions.shape[0]
    out = np.empty((k + FACE_SAMPLES.shape[0] * faces.shape[0], 3))
    out[:k] = positions
    corners = [positions[faces[:, i]] for i in range(3)]
    points = out[k:].reshape(faces.shape[0], FACE_SAMPLES.shape[0], 3)
    for s, (w0, w1, w2) in enumerate(FACE_SAMPLES):
        points[:, s] = w0 * corners[0] + w1 * corners[1] + w2 * corners[2]
    return out


def hausdorff_max(ms, *, sampled: int, target: int, count: int, save: bool = False) -> float:
    """pymeshlab's one-sided Hausdorff distance: the max over the `count` vertices of mesh
    `sampled` (all of them) of their distance to mesh `target` (its surface; its vertices when it
    has no faces), unit frame. With `save`, each sampled vertex's distance is left in its vertex
    quality."""
    import pymeshlab

    radius = pymeshlab.PureValue(2.0 * UNIT_DIAGONAL)  # twice the box diagonal: no sample is dropped
    return float(ms.get_hausdorff_distance(sampledmesh=sampled, targetmesh=target, samplevert=True,
                                           sampleface=False, samplenum=int(count), maxdist=radius,
                                           savesample=save)["max"])


@dataclass(frozen=True, eq=False)
class Clusters:
    """Original faces cut into clusters (module docstring), over one positions array (V,3) f32:
    faces (F,3) int32 (int64 past 2**31 positions), the input faces reordered within each segment so
    that each cluster is a run;
    start (K+1,) int64, cluster k is faces[start[k]:start[k+1]]; first_cluster (S+1,) int64, the
    clusters of segment j are first_cluster[j]:first_cluster[j+1]; box_min / box_max (K,3) float32,
    the box of each cluster's corners (exact positions); centre (K,3) float64, the box centre;
    radius (K,) float64, half the box's diagonal (every corner is within it); surface_vertex (K,) int64, one
    vertex of the cluster (a point on the original surface). Model units (the positions' frame).
    faces are int32 where the positions allow (under 2**31 of them): 12 bytes a face."""

    faces: np.ndarray
    start: np.ndarray
    first_cluster: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    surface_vertex: np.ndarray

    ARRAYS = ("faces", "start", "first_cluster", "box_min", "box_max", "centre", "radius", "surface_vertex")

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.ARRAYS}

    @staticmethod
    def build(positions: np.ndarray, faces: np.ndarray, segments: np.ndarray, *,
              cluster_faces: int = CLUSTER_FACES) -> "Clusters":
        """positions (V,3) f32; faces (F,3) int rows into them; segments (S+1,) int64 increasing face
        indices from 0 to F, runs no cluster crosses (the bake's leaves), each non-empty. Faces are
        ordered by the Morton code (MORTON_CELLS a side) of their corners' box centre within their
        segment's box; every CLUSTER_FACES of them make a cluster."""
        faces = np.asarray(faces)
        segments = np.asarray(segments, np.int64)
        count = faces.shape[0]
        seg_count = segments.size - 1
        if seg_count >= 1 << 33:
            raise ValueError("Clusters.build: more than 2**33 segments")
        if count == 0 or seg_count < 1 or np.any(np.diff(segments) <= 0) or segments[0] != 0 or segments[-1] != count:
            raise ValueError("Clusters.build: segments must split the faces into non-empty runs")
        index_type = np.int32 if positions.shape[0] < 2**31 else np.int64
        face_min, face_max = _face_boxes(positions, faces)
        seg_min = np.minimum.reduceat(face_min, segments[:-1], axis=0).astype(np.float64)
        seg_max = np.maximum.reduceat(face_max, segments[:-1], axis=0).astype(np.float64)
        extent = seg_max - seg_min
        scale = np.divide(MORTON_CELLS, extent, out=np.zeros_like(extent), where=extent > 0)  # flat: one cell
        segment = np.repeat(np.arange(seg_count, dtype=np.int64), np.diff(segments))
        key = np.empty(count, np.int64)  # segment, then Morton code of the face's box centre in it
        for lo in range(0, count, _BUILD_BLOCK):
            hi = min(count, lo + _BUILD_BLOCK)
            seg = segment[lo:hi]
            middle = 0.5 * (face_min[lo:hi].astype(np.float64) + face_max[lo:hi])
            middle -= seg_min[seg]
            middle *= scale[seg]
            cell = np.clip(middle, 0, MORTON_CELLS - 1).astype(np.int64)
            key[lo:hi] = (seg << 30) | _morton10(cell)
        del face_min, face_max, segment
        # stable: ties in face order, so that runs of whole segments cut apart (leaf_arrays.cut_clusters)
        # give the clusters of the whole
        order = np.argsort(key, kind="stable")
        del key
        faces = np.asarray(faces)[order].astype(index_type, copy=False)
        del order

        per_segment = -(-np.diff(segments) // cluster_faces)  # ceil
        first_cluster = np.concatenate([[0], np.cumsum(per_segment)])
        k = int(first_cluster[-1])
        rank = np.arange(k, dtype=np.int64) - np.repeat(first_cluster[:-1], per_segment)
        start = np.concatenate([np.repeat(segments[:-1], per_segment) + cluster_faces * rank, [count]])
        box_min = np.empty((k, 3), np.float32)
        box_max = np.empty((k, 3), np.float32)
        clusters_per_block = max(1, _BUILD_BLOCK // cluster_faces)
        for c0 in range(0, k, clusters_per_block):  # the reordered faces' boxes, a block of clusters at a time
            c1 = min(k, c0 + clusters_per_block)
            block_min, block_max = _face_boxes(positions, faces[start[c0]:start[c1]])
            box_min[c0:c1] = np.minimum.reduceat(block_min, start[c0:c1] - start[c0], axis=0)
            box_max[c0:c1] = np.maximum.reduceat(block_max, start[c0:c1] - start[c0], axis=0)
        lo, hi = box_min.astype(np.float64), box_max.astype(np.float64)
        centre = 0.5 * (lo + hi)
        # every corner lies in the box, so within half its diagonal of the centre (rounded up)
        radius = 0.5 * np.sqrt(((hi - lo) ** 2).sum(axis=1)) * (1.0 + 1e-12)
        return Clusters(faces=faces, start=start, first_cluster=first_cluster, box_min=box_min, box_max=box_max,
                        centre=centre, radius=radius, surface_vertex=faces[start[:-1], 0].astype(np.int64))


def _face_boxes(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F,3) float32 min and max corner of each face, in blocks."""
    face_min = np.empty((faces.shape[0], 3), np.float32)
    face_max = np.empty((faces.shape[0], 3), np.float32)
    for lo in range(0, faces.shape[0], _BUILD_BLOCK):
        block = faces[lo:lo + _BUILD_BLOCK]
        a, b, c = (np.asarray(positions[block[:, j]], np.float32) for j in range(3))
        end = lo + block.shape[0]
        np.minimum(np.minimum(a, b, out=face_min[lo:end]), c, out=face_min[lo:end])
        np.maximum(np.maximum(a, b, out=face_max[lo:end]), c, out=face_max[lo:end])
    return face_min, face_max


def _morton10(cell: np.ndarray) -> np.ndarray:
    """(n,3) int64 cell coordinates below 2**10 -> (n,) int64 30-bit Morton codes (x lowest)."""
    spread = cell & 0x3FF
    spread = (spread | (spread << 16)) & 0x030000FF
    spread = (spread | (spread << 8)) & 0x0300F00F
    spread = (spread | (spread << 4)) & 0x030C30C3
    spread = (spread | (spread << 2)) & 0x09249249
    return spread[:, 0] | (spread[:, 1] << 1) | (spread[:, 2] << 2)


def measure_pruned(lod: tuple[np.ndarray, np.ndarray], original: tuple[np.ndarray, np.ndarray], *,
                   allow_whole: bool = False) -> float:
    """`measure`'s float, pruned: the original made one run of clusters (tests; the bake builds
    its clusters once, over all leaves, and calls measure_clustered). allow_whole: measure whole, or
    the original's vertices as a point set, where pruning cannot pay (measure_clustered's `whole`:
    the original with only the vertices its faces use, as pruning measures it); off, it always
    prunes."""
    faces = np.asarray(original[1])
    clusters = Clusters.build(original[0], faces, np.array([0, faces.shape[0]], np.int64))
    p = np.asarray(original[0], np.float64)
    return measure_clustered(lod, original[0], clusters, first=0, last=clusters.radius.size,
                             original_box=(p.min(axis=0), p.max(axis=0)),
                             whole=(lambda: compact(original[0], faces)[:2]) if allow_whole else None)


def measure_clustered(lod: tuple[np.ndarray, np.ndarray], positions: np.ndarray, clusters: Clusters, *,
                      first: int, last: int, original_box: tuple[np.ndarray, np.ndarray] | None = None,
                      whole: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None) -> float:
    """`measure(lod, original)` of the original made of clusters first..last-1 (their faces into
    `positions`, (V,3) float32), pruned (module docstring); the same float. original_box: the
    original vertices' (min, max), which set the unit frame with the LOD's; by default the clusters'
    boxes (equal when every original vertex is a face corner, as in the bake's compacted leaves).
    whole: the original as (positions, faces), every position a face corner (as in the bake's
    compacted leaves), for where the clusters' bounds show that pruning the original -> LOD
    direction cannot pay (more than PRUNE_MAX_SHARE of them above the floor: a LOD that stays within
    a cluster's radius of the surface everywhere): below POINT_SET_FROM_VERTICES vertices the node
    is measured whole (`measure`); from it, every original vertex is measured to the LOD in one call
    as a point set, and the LOD's samples only where those points leave them within reach of
    raising the maximum, against the clusters there (on a node of several models, a few samples
    and clusters: the whole original never becomes one pymeshlab mesh)."""
    if original_box is None:
        original_box = (clusters.box_min[first:last].min(axis=0), clusters.box_max[first:last].max(axis=0))
    pruning = _Pruning(lod, positions, clusters, first=first, last=last, original_box=original_box)
    # original -> LOD, by clusters in decreasing order of their bound d(c, LOD) + r
    centre_distance = pruning.distances(pruning.centre, 0)
    finite = np.isfinite(centre_distance)
    bound = np.where(finite, centre_distance + pruning.radius + PRUNE_MARGIN, np.inf)
    floor = float(np.max(centre_distance[finite] - pruning.radius[finite], initial=0.0)) - PRUNE_MARGIN
    points = None
    if whole is not None and np.mean(bound > floor) > PRUNE_MAX_SHARE:
        original = whole()
        if original[0].shape[0] < POINT_SET_FROM_VERTICES:
            return measure(lod, original)
        # every original vertex to the LOD in one call, as a point set (this direction needs no
        # faces); the same points then bound the LOD's samples' distances from above
        points = pruning.add_points(pruning.frame.to_local(original[0]))
        best = hausdorff_max(pruning.ms, sampled=points, target=0, count=original[0].shape[0])
    else:
        best = pruning.original_to_lod(bound, floor=floor)
    if not np.isfinite(best):
        return float("nan")
    best = pruning.lod_to_original(best, on_surface=points)
    return best / pruning.frame.scale if np.isfinite(best) else float("nan")


class _Pruning:
    """One pruned measure (`measure_clustered`): a pymeshlab MeshSet whose mesh 0 is the LOD, the
    unit frame of the LOD and the original, the LOD's samples, and clusters first..last-1 in that
    frame (centre (K,3), radius (K,)); each measured point set is added to the MeshSet."""

    def __init__(self, lod: tuple[np.ndarray, np.ndarray], positions: np.ndarray, clusters: Clusters, *, first: int,
                 last: int, original_box: tuple[np.ndarray, np.ndarray]):
        import pymeshlab

        lod_positions = np.asarray(lod[0], np.float64)
        lo = np.minimum(lod_positions.min(axis=0), np.asarray(original_box[0], np.float64))
        hi = np.maximum(lod_positions.max(axis=0), np.asarray(original_box[1], np.float64))
        self.frame = NodeFrame.of_box(lo, hi)
        lod_p = self.frame.to_local(lod[0])
        self.samples = surface_samples(lod_p, lod[1])
        self.centre = self.frame.to_local(clusters.centre[first:last])
        self.radius = clusters.radius[first:last] * self.frame.scale
        self.start = clusters.start[first:last + 1]
        self.positions, self.clusters, self.first, self.last = positions, clusters, first, last
        self.ms = pymeshlab.MeshSet()
        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=lod_p, face_matrix=lod[1]))  # mesh 0: the LOD

    def add_points(self, points: np.ndarray) -> int:
        """Add points (b,3), unit frame, to the MeshSet as a mesh without faces; its id."""
        import pymeshlab

        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
        return self.ms.current_mesh_id()

    def distances(self, points: np.ndarray, target: int) -> np.ndarray:
        """(b,) each of points (b,3)'s distance to mesh `target`, unit frame."""
        import pymeshlab

        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
        sampled = self.ms.current_mesh_id()
        hausdorff_max(self.ms, sampled=sampled, target=target, count=points.shape[0], save=True)
        return self.ms.mesh(sampled).vertex_scalar_array()

    def max_distance(self, points: np.ndarray, target: int) -> float:
        """The largest of points (b,3)'s distances to mesh `target`, unit frame."""
        import pymeshlab

        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
        return hausdorff_max(self.ms, sampled=self.ms.current_mesh_id(), target=target, count=points.shape[0])

    def faces_of(self, cluster_ids: np.ndarray) -> np.ndarray:
        """The faces (rows into positions) of the clusters cluster_ids (local to first..last-1)."""
        begin, end = self.start[cluster_ids], self.start[cluster_ids + 1]
        lengths = end - begin
        rows = np.repeat(begin - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths) + np.arange(lengths.sum())
        return self.clusters.faces[rows]

    def original_to_lod(self, bound: np.ndarray, *, floor: float) -> float:
        """The largest distance of an original vertex to the LOD (unit frame; NaN if pymeshlab gives
        none): clusters in decreasing order of their bound (K,), in batches growing 4x, until the
        next bound is not above the maximum so far nor the floor (a cluster's vertices are all at
        least d(c, LOD) - r from the LOD); the result stays a measured value."""
        order = np.argsort(-bound, kind="stable")
        best, at, batch = 0.0, 0, 1
        while at < order.size and bound[order[at]] > max(best, floor):
            take = order[at:at + batch]
            take = take[bound[take] > max(best, floor)]
            vertices = np.unique(self.faces_of(take))
            value = self.max_distance(self.frame.to_local(self.positions[vertices]), 0)
            if not np.isfinite(value):
                return float("nan")
            best = max(best, value)
            at += batch
            batch *= 4
        return best

    def lod_to_original(self, best: float, *, on_surface: int | None = None) -> float:
        """max(best, the largest distance of a LOD sample to the original surface), unit frame (NaN
        if pymeshlab gives none): upper bounds from points on the original surface (the mesh
        `on_surface` of this MeshSet, points only; by default the clusters' surface vertices), then
        the samples that can still raise the maximum, against the clusters within their reach."""
        if on_surface is None:
            surface = self.clusters.surface_vertex[self.first:self.last]
            on_surface = self.add_points(self.frame.to_local(self.positions[surface]))
        reach = self.distances(self.samples, on_surface)
        reach = np.where(np.isfinite(reach), reach + PRUNE_MARGIN, np.inf)
        candidates = np.flatnonzero(reach > best)
        candidates = candidates[np.argsort(-reach[candidates], kind="stable")]
        if candidates.size > WHOLE_TARGET_SHARE * self.samples.shape[0]:
            every_face = self.faces_of(np.arange(self.last - self.first))
            value = _max_to_faces(self.ms, self.samples[candidates], positions=self.positions, faces=every_face,
                                  frame=self.frame)
            return max(best, value) if np.isfinite(value) else float("nan")
        at, batch = 0, FIRST_SAMPLE_BATCH
        centre_sq = (self.centre ** 2).sum(axis=1)
        while at < candidates.size:
            take = candidates[at:at + batch]
            take = take[reach[take] > best]
            at += batch
            batch *= 4
            if take.size == 0:
                break
            needed = _within_reach(self.samples[take], reach[take], centre=self.centre, centre_sq=centre_sq,
                                   radius=self.radius)
            value = _max_to_faces(self.ms, self.samples[take], positions=self.positions, faces=self.faces_of(needed),
                                  frame=self.frame)
            if not np.isfinite(value):
                return float("nan")
            best = max(best, value)
        return best


def _within_reach(points: np.ndarray, reach: np.ndarray, *, centre: np.ndarray, centre_sq: np.ndarray,
                  radius: np.ndarray) -> np.ndarray:
    """Indices of the clusters (centre (K,3), radius (K,), unit frame) with |p - c| - r <= reach(p)
    (+ PRUNE_MARGIN) for some row p of points (b,3)."""
    needed = np.zeros(centre.shape[0], bool)
    rows = max(1, _REACH_BLOCK // max(1, centre.shape[0]))
    for lo in range(0, points.shape[0], rows):
        p = points[lo:lo + rows]
        squared = (p ** 2).sum(axis=1)[:, None] - 2.0 * (p @ centre.T) + centre_sq[None, :]
        limit = reach[lo:lo + rows, None] + radius[None, :] + PRUNE_MARGIN
        needed |= np.any(squared <= limit * limit, axis=0)
    return np.flatnonzero(needed)


def _max_to_faces(ms, points: np.ndarray, *, positions: np.ndarray, faces: np.ndarray, frame: NodeFrame) -> float:
    """Max over points (b,3) unit frame of their distance to the surface of `faces` (rows into
    positions, model units): one target mesh of just those faces, compacted."""
    import pymeshlab

    used, local = np.unique(faces, return_inverse=True)
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=frame.to_local(positions[used]),
                               face_matrix=local.reshape(-1, 3).astype(np.int32)))
    target = ms.current_mesh_id()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
    return hausdorff_max(ms, sampled=ms.current_mesh_id(), target=target, count=points.shape[0])
