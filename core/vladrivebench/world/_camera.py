"""A pinhole front camera that renders the world as a model would see it.

The ground is ray-cast per pixel: the ego drives on a flat plane, so the ground point each pixel sees is
fixed in the ego frame and computed once; each frame only moves those points by the ego's pose and asks
the road geometry for their material. Actors, road features and scenery are boxes drawn over the ground
in painter's order (farthest first), each visible face filled as a convex polygon and shaded by a fixed
sun. Visual salience is therefore physical: a pedestrian 50 m away covers a handful of pixels, a car in
the lane ahead covers a large block.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from vladrivebench.records import Actor, CameraSpec, EgoState
from vladrivebench.world._roads import (
    GRASS,
    KERB,
    MARK_WHITE,
    MARK_YELLOW,
    ROAD,
    SIDEWALK,
    Prop,
    RoadGeometry,
)

MATERIAL_COLOURS = np.zeros((6, 3), dtype=float)
MATERIAL_COLOURS[GRASS] = (86, 112, 64)
MATERIAL_COLOURS[SIDEWALK] = (150, 146, 138)
MATERIAL_COLOURS[KERB] = (196, 194, 188)
MATERIAL_COLOURS[ROAD] = (72, 72, 76)
MATERIAL_COLOURS[MARK_WHITE] = (232, 232, 232)
MATERIAL_COLOURS[MARK_YELLOW] = (222, 184, 52)

SKY_TOP = np.array((92, 142, 210), dtype=float)
SKY_HORIZON = np.array((190, 214, 236), dtype=float)
HAZE = np.array((176, 190, 204), dtype=float)
SUN = np.array((0.35, -0.45, 0.82)) / np.linalg.norm((0.35, -0.45, 0.82))

PROP_RANGE = 150.0
"""Scenery farther than this from the camera is not drawn (level of detail; it is small and hazy there)."""
LIGHT_HEAD_HEIGHT = 1.0
"""A traffic light actor's head occupies ``[height - 1.0, height]`` above the ground."""
SIGN_PLATE_SIZE = 0.75
"""A stop sign actor's plate occupies ``[height - 0.75, height]``."""
LAMP_COLOURS = {"red": (255, 40, 30), "yellow": (255, 200, 30), "green": (40, 235, 90)}
LAMP_OFF = {"red": (70, 22, 20), "yellow": (70, 60, 20), "green": (20, 60, 30)}
LAMP_ORDER = ("red", "yellow", "green")
PROP_COLOURS = {"building": ((150, 140, 130), (120, 126, 138), (170, 158, 136), (105, 100, 98)),
                "house": ((196, 180, 150), (178, 150, 130)), "tree": ((52, 110, 48),)}


@dataclass(frozen=True)
class Solid:
    """One box to draw: centre (x, y) on the ground plane, heading ``yaw``, vertical extent ``z0``..``z1``.
    ``emissive`` solids (lit lamps, sign faces) are not shaded and cover at least one pixel when in view;
    ``front_only`` solids show only their face pointing along ``yaw`` (a lamp is dark from behind)."""

    x: float
    y: float
    yaw: float
    length: float
    width: float
    z0: float
    z1: float
    colour: tuple[float, float, float]
    emissive: bool = False
    front_only: bool = False


@dataclass(frozen=True)
class _SolidGroup:
    """Solids drawn together (one actor's or one prop's), as arrays, with their mean position: groups are
    painted farthest first."""

    params: np.ndarray  # (N, 7): x, y, yaw, length, width, z0, z1
    colours: np.ndarray  # (N, 3) float
    emissive: np.ndarray  # (N,) bool
    front_only: np.ndarray  # (N,) bool
    x: float
    y: float

    @property
    def count(self) -> int:
        return len(self.params)

    @classmethod
    def of(cls, solids: Sequence[Solid]) -> _SolidGroup:
        count = max(len(solids), 1)
        return cls(np.array([(sd.x, sd.y, sd.yaw, sd.length, sd.width, sd.z0, sd.z1) for sd in solids],
                            dtype=float).reshape(-1, 7),
                   np.array([sd.colour for sd in solids], dtype=float).reshape(-1, 3),
                   np.array([sd.emissive for sd in solids], dtype=bool), np.array([sd.front_only for sd in solids],
                                                                                  dtype=bool),
                   sum(sd.x for sd in solids) / count, sum(sd.y for sd in solids) / count)

    @classmethod
    def joined(cls, groups: Sequence[_SolidGroup]) -> _SolidGroup:
        return cls(np.concatenate([g.params for g in groups]), np.concatenate([g.colours for g in groups]),
                   np.concatenate([g.emissive for g in groups]), np.concatenate([g.front_only for g in groups]),
                   0.0, 0.0)


_PROP_GROUPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _road_prop_groups(road: RoadGeometry) -> list[tuple[float, float, _SolidGroup]]:
    """(x, y, solids) of every prop of ``road``: the scenery never changes, so it is built once per road."""
    groups = _PROP_GROUPS.get(road)
    if groups is None:
        groups = [(prop.x, prop.y, _SolidGroup.of(solids_for_prop(prop, i))) for i, prop in enumerate(road.props)]
        _PROP_GROUPS[road] = groups
    return groups


_UNIT_CORNERS = np.array(
    [[sx, sy, sz] for sz in (0, 1) for sy in (-1, 1) for sx in (-1, 1)], dtype=float
)  # index = sx_bit + 2 * sy_bit + 4 * sz_bit
_FACES = (  # (corner indices counter-clockwise seen from outside, local outward normal); front face first
    ((1, 3, 7, 5), (1.0, 0.0, 0.0)),
    ((0, 4, 6, 2), (-1.0, 0.0, 0.0)),
    ((2, 6, 7, 3), (0.0, 1.0, 0.0)),
    ((0, 1, 5, 4), (0.0, -1.0, 0.0)),
    ((4, 5, 7, 6), (0.0, 0.0, 1.0)),
    ((0, 2, 3, 1), (0.0, 0.0, -1.0)),
)
_FACE_CORNERS = np.array([corners for corners, _ in _FACES])
_FACE_NORMALS = np.array([normal for _, normal in _FACES])
_NEXT_CORNER = np.array([1, 2, 3, 0])


class Camera:
    """A camera mounted on the ego: ``width`` × ``height`` pixels, horizontal field of view ``hfov_deg``,
    at ``mount_height`` metres above the ground, ``mount_forward`` metres ahead of the ego's centre and
    ``mount_left`` to its left, turned left by ``yaw_deg`` and pitched down by ``pitch_deg`` (the defaults:
    the front camera). :meth:`render` returns an ``(height, width, 3)`` uint8 image; :meth:`from_spec`
    builds one from a :class:`~vladrivebench.records.CameraSpec`."""

    def __init__(self, width: int = 160, height: int = 80, hfov_deg: float = 90.0, mount_height: float = 1.6,
                 mount_forward: float = 0.8, pitch_deg: float = 0.0, max_range: float = 250.0,
                 mount_left: float = 0.0, yaw_deg: float = 0.0):
        if width < 8 or height < 8:
            raise ValueError(f"camera image must be at least 8×8 pixels, got {width}×{height}")
        if not 10.0 <= hfov_deg <= 170.0:
            raise ValueError(f"camera hfov_deg must be between 10 and 170, got {hfov_deg}")
        self.width, self.height = int(width), int(height)
        self.mount_height, self.mount_forward = float(mount_height), float(mount_forward)
        self.mount_left, self.yaw = float(mount_left), math.radians(yaw_deg)
        self.focal = (self.width / 2) / math.tan(math.radians(hfov_deg) / 2)
        self.cx, self.cy = self.width / 2, self.height / 2
        self.pitch = math.radians(pitch_deg)
        self.max_range = float(max_range)
        self.near = 0.05
        self._precompute_ground()

    def _precompute_ground(self) -> None:
        u = (np.arange(self.width) + 0.5 - self.cx) / self.focal
        v = (np.arange(self.height) + 0.5 - self.cy) / self.focal
        right, down = np.meshgrid(u, v)
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        forward_e = cp - down * sp
        down_e = sp + down * cp
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(down_e > 1e-9, self.mount_height / down_e, np.inf)
            fwd, left = t * forward_e, -t * right  # inf × 0 above the horizon: NaN, masked out below
        dist = np.hypot(fwd, left)
        hits = np.isfinite(t) & (dist <= self.max_range) & (fwd > 0)
        self._ground_index = np.flatnonzero(hits)
        fwd, left = fwd.ravel()[self._ground_index], left.ravel()[self._ground_index]
        if self.yaw:  # camera-local (forward, left) → ego frame; the front camera keeps its exact values
            cy, sy = math.cos(self.yaw), math.sin(self.yaw)
            fwd, left = cy * fwd - sy * left, sy * fwd + cy * left
        self._ground_fwd = fwd + self.mount_forward
        self._ground_left = left + self.mount_left if self.mount_left else left
        haze = np.clip(dist.ravel()[self._ground_index] / self.max_range, 0.0, 1.0) ** 1.2 * 0.65
        # Each ground pixel's colour for every material, hazed by its distance: (pixels, materials, rgb).
        hazed = MATERIAL_COLOURS[None] * (1 - haze[:, None, None]) + HAZE * haze[:, None, None]
        self._ground_lut = _to_uint8(hazed)
        self._ground_rows = np.arange(len(self._ground_index))
        self._ground_lut_flat = self._ground_lut.reshape(-1, 3)  # row = pixel * materials + material
        self._ground_base = self._ground_rows * self._ground_lut.shape[1]
        # Sky: a vertical gradient by elevation, and haze at the horizon where the ground ran out of range.
        elevation = np.clip(-down_e / np.maximum(np.hypot(forward_e, down_e), 1e-9), 0.0, 1.0)
        blend = np.sqrt(elevation)[..., None]
        background = SKY_HORIZON * (1 - blend) + SKY_TOP * blend
        background[~hits & (down_e > 0)] = HAZE
        self._background = _to_uint8(background.reshape(-1, 3))

    # -- public -------------------------------------------------------------------------------------
    def render(self, road: RoadGeometry, ego: EgoState, actors: Iterable[Actor] = (),
               props: Sequence[Prop] | None = None) -> np.ndarray:
        """The camera image of ``road`` with ``actors`` (and the road's scenery unless ``props`` is given)."""
        image = self._background.copy()
        c, s = math.cos(ego.yaw), math.sin(ego.yaw)
        gx = ego.x + c * self._ground_fwd - s * self._ground_left
        gy = ego.y + s * self._ground_fwd + c * self._ground_left
        image[self._ground_index] = self._ground_lut_flat.take(self._ground_base + road.classify(gx, gy), axis=0)
        image = image.reshape(self.height, self.width, 3)
        groups = [_SolidGroup.of(solids_for_actor(a)) for a in actors]
        cam_x, cam_y, _ = self.camera_position(ego)
        if props is None:
            scenery = _road_prop_groups(road)
        else:
            scenery = [(prop.x, prop.y, _SolidGroup.of(solids_for_prop(prop, i))) for i, prop in enumerate(props)]
        for x, y, group in scenery:
            if math.hypot(x - cam_x, y - cam_y) <= PROP_RANGE:
                groups.append(group)
        self._draw_groups(image, ego, groups)
        return image

    @classmethod
    def from_spec(cls, spec: CameraSpec, max_range: float = 250.0) -> Camera:
        """The camera a :class:`~vladrivebench.records.CameraSpec` describes."""
        return cls(spec.width, spec.height, spec.hfov_deg, mount_height=spec.z, mount_forward=spec.x,
                   pitch_deg=spec.pitch_deg, max_range=max_range, mount_left=spec.y, yaw_deg=spec.yaw_deg)

    def camera_position(self, ego: EgoState) -> np.ndarray:
        """World position (x, y, z) of the camera."""
        x, y = ego.to_world_frame(self.mount_forward, self.mount_left)
        return np.array([x, y, self.mount_height])

    # -- drawing ------------------------------------------------------------------------------------
    def _draw_groups(self, image: np.ndarray, ego: EgoState, groups: list[_SolidGroup]) -> None:
        cam = self.camera_position(ego)
        ordered = [(-math.hypot(group.x - cam[0], group.y - cam[1]), index)
                   for index, group in enumerate(groups) if group.count]
        ordered.sort()
        if ordered:
            self._draw_solids(image, ego, cam, _SolidGroup.joined([groups[index] for _, index in ordered]))

    def _to_camera(self, ego: EgoState, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) → camera frame (..., 3): (right, down, depth along the optical axis)."""
        c, s = math.cos(ego.yaw), math.sin(ego.yaw)
        dx, dy = points[..., 0] - ego.x, points[..., 1] - ego.y
        fwd = c * dx + s * dy - self.mount_forward
        left = -s * dx + c * dy
        if self.mount_left:
            left = left - self.mount_left
        if self.yaw:  # ego frame → camera-local (forward, left)
            cy, sy = math.cos(self.yaw), math.sin(self.yaw)
            fwd, left = cy * fwd + sy * left, -sy * fwd + cy * left
        down = self.mount_height - points[..., 2]
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        return np.stack([-left, -fwd * sp + down * cp, fwd * cp + down * sp], axis=-1)

    def _draw_solids(self, image: np.ndarray, ego: EgoState, cam: np.ndarray, solids: _SolidGroup) -> None:
        """Project every solid at once, cull what is out of view, then fill the visible faces in order."""
        x, y, yaw, length, width, z0, z1 = solids.params.T
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        lx = _UNIT_CORNERS[:, 0] * (length[:, None] / 2)
        ly = _UNIT_CORNERS[:, 1] * (width[:, None] / 2)
        world = np.stack([x[:, None] + c * lx - s * ly, y[:, None] + s * lx + c * ly,
                          np.where(_UNIT_CORNERS[:, 2] > 0, z1[:, None], z0[:, None])], axis=-1)
        camera = self._to_camera(ego, world)  # (N, 8, 3)
        depth = camera[..., 2]
        all_front = np.all(depth > self.near, axis=1)
        safe = np.where(depth > self.near, depth, 1.0)
        u = self.cx + self.focal * camera[..., 0] / safe
        v = self.cy + self.focal * camera[..., 1] / safe
        off_image = (u.max(1) < 0) | (u.min(1) > self.width) | (v.max(1) < 0) | (v.min(1) > self.height)
        keep = ~np.all(depth < self.near, axis=1) & ~(all_front & off_image)
        normals = np.stack([c * _FACE_NORMALS[:, 0] - s * _FACE_NORMALS[:, 1],
                            s * _FACE_NORMALS[:, 0] + c * _FACE_NORMALS[:, 1],
                            np.broadcast_to(_FACE_NORMALS[:, 2], c.shape[:1] + (6,))], axis=-1)  # (N, 6, 3)
        face_centres = world[:, _FACE_CORNERS].mean(axis=2)
        facing = np.einsum("nfk,nfk->nf", normals, cam - face_centres) > 0.0
        shade = 0.55 + 0.45 * np.clip(normals @ SUN, 0.0, None)
        base, emissive, front_only = solids.colours, solids.emissive, solids.front_only
        shade[emissive] = 1.0
        face_colours = _to_uint8(base[:, None, :] * shade[..., None])  # (N, 6, rgb)
        drawn = keep[:, None] & facing
        drawn[front_only, 1:] = False
        solid_index, face_index = np.nonzero(drawn)  # painting order: solid by solid, faces in order
        faces = _FaceList.from_projection(u, v, camera, all_front, solid_index, face_index, self)
        faces.fill(image, face_colours[faces.solid, faces.face], emissive[faces.solid])


@dataclass
class _FaceList:
    """The faces of one frame to fill, in painting order: polygons in pixel coordinates (each padded to the
    longest with zero-length edges at its end) and what :func:`_fill_convex` derives from them (box, signed
    area, centroid), computed with the same float operations in the same order, for every face at once."""

    solid: np.ndarray
    face: np.ndarray
    edge_u: np.ndarray  # (M, K) start of each edge
    edge_v: np.ndarray
    edge_du: np.ndarray  # (M, K) end minus start (0 for padding)
    edge_dv: np.ndarray
    box: np.ndarray  # (M, 4) int: u0, u1, v0, v1 clipped to the image (u0 >= u1 or v0 >= v1: empty)
    area: np.ndarray  # twice the signed area
    centroid: np.ndarray  # (M, 2)
    counts: np.ndarray  # (M,) vertices of each polygon (the rest of its row is padding)
    width: int
    height: int

    @classmethod
    def from_projection(cls, u: np.ndarray, v: np.ndarray, camera: np.ndarray, all_front: np.ndarray,
                        solid_index: np.ndarray, face_index: np.ndarray, cam: Camera) -> _FaceList:
        corners = _FACE_CORNERS[face_index]  # (M, 4)
        front = all_front[solid_index]
        pu = np.take_along_axis(u[solid_index], corners, axis=1)
        pv = np.take_along_axis(v[solid_index], corners, axis=1)
        if front.all():  # no face crosses the near plane (the usual frame): quadrilaterals only
            nu, nv = pu[:, _NEXT_CORNER], pv[:, _NEXT_CORNER]
            terms = pu * nv - nu * pv
            area = ((terms[:, 0] + terms[:, 1]) + terms[:, 2]) + terms[:, 3]
            centroid = np.stack([(((pu[:, 0] + pu[:, 1]) + pu[:, 2]) + pu[:, 3]) / 4,
                                 (((pv[:, 0] + pv[:, 1]) + pv[:, 2]) + pv[:, 3]) / 4], axis=1)
            box = _boxes(pu.min(axis=1), pu.max(axis=1), pv.min(axis=1), pv.max(axis=1), cam)
            return cls(solid_index, face_index, pu, pv, nu - pu, nv - pv, box, area, centroid,
                       np.full(len(pu), 4, dtype=np.int64), cam.width, cam.height)
        polygons: list[tuple[int, list[float], list[float]]] = []
        for m in np.flatnonzero(~front):  # faces crossing the near plane: clipped one by one (rare)
            polygon = _clip_near(camera[solid_index[m], _FACE_CORNERS[face_index[m]]], cam.near)
            if len(polygon) >= 3:
                polygons.append((int(m), (cam.cx + cam.focal * polygon[:, 0] / polygon[:, 2]).tolist(),
                                 (cam.cy + cam.focal * polygon[:, 1] / polygon[:, 2]).tolist()))
        rows = np.flatnonzero(front)
        count = max([4] + [len(pu_) for _, pu_, _ in polygons])
        keep = np.concatenate([rows, np.array([m for m, _, _ in polygons], dtype=int)])
        order = np.argsort(keep, kind="stable")
        n_front = len(rows)
        edge_u = np.zeros((len(keep), count))
        edge_v = np.zeros((len(keep), count))
        edge_du = np.zeros((len(keep), count))
        edge_dv = np.zeros((len(keep), count))
        box = np.zeros((len(keep), 4), dtype=np.int64)
        area = np.zeros(len(keep))
        centroid = np.zeros((len(keep), 2))
        fu, fv = pu[rows], pv[rows]
        nu, nv = fu[:, _NEXT_CORNER], fv[:, _NEXT_CORNER]
        edge_u[:n_front, :4], edge_v[:n_front, :4] = fu, fv
        edge_du[:n_front, :4] = nu - fu
        edge_dv[:n_front, :4] = nv - fv
        terms = fu * nv - nu * fv
        area[:n_front] = ((terms[:, 0] + terms[:, 1]) + terms[:, 2]) + terms[:, 3]
        centroid[:n_front, 0] = (((fu[:, 0] + fu[:, 1]) + fu[:, 2]) + fu[:, 3]) / 4
        centroid[:n_front, 1] = (((fv[:, 0] + fv[:, 1]) + fv[:, 2]) + fv[:, 3]) / 4
        box[:n_front] = _boxes(fu.min(axis=1), fu.max(axis=1), fv.min(axis=1), fv.max(axis=1), cam)
        for row, (_, pu_, pv_) in enumerate(polygons, start=n_front):
            n = len(pu_)
            edge_u[row, :n], edge_v[row, :n] = pu_, pv_
            edge_u[row, n:], edge_v[row, n:] = pu_[0], pv_[0]
            edge_du[row, :n] = [pu_[(i + 1) % n] - pu_[i] for i in range(n)]
            edge_dv[row, :n] = [pv_[(i + 1) % n] - pv_[i] for i in range(n)]
            area[row] = sum(pu_[i] * pv_[(i + 1) % n] - pu_[(i + 1) % n] * pv_[i] for i in range(n))
            centroid[row] = sum(pu_) / n, sum(pv_) / n
            box[row] = _boxes(np.array([min(pu_)]), np.array([max(pu_)]), np.array([min(pv_)]),
                              np.array([max(pv_)]), cam)[0]
        picked = keep[order]
        counts = np.array([4] * n_front + [len(pu_) for _, pu_, _ in polygons], dtype=np.int64)
        return cls(solid_index[picked], face_index[picked], edge_u[order], edge_v[order], edge_du[order],
                   edge_dv[order], box[order], area[order], centroid[order], counts[order], cam.width,
                   cam.height)

    def polygon(self, m: int) -> tuple[list[float], list[float]]:
        """Face ``m``'s vertices (u, v) in pixel coordinates."""
        count = int(self.counts[m])
        return self.edge_u[m, :count].tolist(), self.edge_v[m, :count].tolist()

    def fill(self, image: np.ndarray, colours: np.ndarray, at_least_one: np.ndarray) -> None:
        """Paint every face in order, exactly as :func:`_fill_convex` face by face would."""
        u0, u1, v0, v1 = self.box.T
        nonempty = (u0 < u1) & (v0 < v1)
        solid = nonempty & (np.abs(self.area) > 1e-12)
        small = solid & ((u1 - u0) * (v1 - v0) <= _SMALL_BOX)
        sign = np.where(self.area > 0, 1.0, -1.0)
        pixels, owners = [], []
        faces = np.flatnonzero(small)
        if len(faces):
            owner, rows, cols = _box_cells(self.box, faces)
            inside = self._inside_small(faces, owner, rows, cols, sign)
            pixels.append(rows[inside] * self.width + cols[inside])
            owners.append(faces[owner[inside]])
        faces = np.flatnonzero(solid & ~small)
        if len(faces):
            pixel, owner = self._spans_large(faces, sign)
            pixels.append(pixel)
            owners.append(owner)
        pixel = np.concatenate(pixels) if pixels else np.zeros(0, dtype=np.int64)
        owner = np.concatenate(owners) if owners else np.zeros(0, dtype=np.int64)
        painted = np.bincount(owner, minlength=len(self.area))
        coverage = np.abs(self.area) / 2
        cu, cv = self.centroid.T
        blends = np.flatnonzero(nonempty & (painted == 0) & (coverage < 1.0) & (cu >= 0) & (cu < self.width)
                                & (cv >= 0) & (cv < self.height))
        flat = image.reshape(-1, 3)
        blended = self._blend_pixels(flat, pixel, owner, blends, colours, at_least_one, coverage)
        _paint_last(flat, pixel, owner, colours)
        for index, value in blended.items():
            flat[index] = value

    def _blend_pixels(self, flat: np.ndarray, pixel: np.ndarray, owner: np.ndarray, blends: np.ndarray,
                      colours: np.ndarray, at_least_one: np.ndarray, coverage: np.ndarray) -> dict:
        """The final colour of every pixel a sub-pixel face blends into: the faces painting it and blending
        into it replayed in order from the colour under all faces (the few such pixels, one by one)."""
        if not len(blends):
            return {}
        cu, cv = self.centroid[blends].T
        targets = cv.astype(np.int64) * self.width + cu.astype(np.int64)
        events: dict[int, list] = {}
        for face, index in zip(blends.tolist(), targets.tolist(), strict=True):
            share = 1.0 if at_least_one[face] else coverage[face]
            events.setdefault(index, []).append((face, share))
        hits = np.flatnonzero(np.isin(pixel, targets))
        for index, face in zip(pixel[hits].tolist(), owner[hits].tolist(), strict=True):
            events[index].append((face, None))
        result = {}
        palette = colours.tolist()
        for index, steps in events.items():
            value = flat[index].tolist()
            for face, share in sorted(steps, key=lambda step: step[0]):
                if share is None:
                    value = palette[face]
                else:  # _to_uint8 of the blend, channel by channel in the same float operations
                    share = float(share)
                    value = [int(min(max(a * (1.0 - share) + b * share + 0.5, 0.0), 255.0))
                             for a, b in zip(value, palette[face], strict=True)]
            result[index] = value
        return result

    def _inside_small(self, faces, owner, rows, cols, sign):
        """The per-pixel half-plane test of :func:`_fill_small`."""
        f = faces[owner]
        pu, pv = cols + 0.5, rows + 0.5
        inside = np.ones(len(f), dtype=bool)
        for e in range(self.edge_u.shape[1]):
            au, av, du, dv = self.edge_u[f, e], self.edge_v[f, e], self.edge_du[f, e], self.edge_dv[f, e]
            inside &= sign[f] * (du * (pv - av) - dv * (pu - au)) >= 0.0
        return inside

    def _spans_large(self, faces: np.ndarray, sign: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat pixel, face) painted by each of ``faces`` with the row-interval test of :func:`_fill_convex`:
        each edge bounds every row's span from one side; a row paints the columns whose centre lies in
        ``[lo, hi]``, found from an estimate corrected by that exact comparison."""
        u0, u1, v0, v1 = self.box[faces].T
        heights = v1 - v0
        row_face = np.repeat(np.arange(len(faces)), heights)
        row = np.arange(len(row_face)) - np.repeat(np.cumsum(heights) - heights, heights) + v0[row_face]
        row_centre = _PIXEL_CENTRES[row]
        lo = np.full(len(row_face), -np.inf)
        hi = np.full(len(row_face), np.inf)
        face = faces[row_face]
        face_sign = sign[face]
        with np.errstate(divide="ignore", invalid="ignore"):
            for e in range(self.edge_u.shape[1]):
                au, av = self.edge_u[face, e], self.edge_v[face, e]
                du, dv = self.edge_du[face, e], self.edge_dv[face, e]
                k = -face_sign * dv
                c = face_sign * (du * (row_centre - av) + dv * au)
                bound = -c / k
                lo = np.where(k > 0.0, np.maximum(lo, bound), lo)
                hi = np.where(k < 0.0, np.minimum(hi, bound), hi)
                hi = np.where((k == 0.0) & (c < 0.0), -np.inf, hi)
        first, last = u0[row_face], u1[row_face]
        start = np.minimum(np.maximum(np.ceil(lo - 0.5), first), last).astype(np.int64)
        start = np.where((start > first) & (start - 0.5 >= lo), start - 1, start)  # column start-1 is inside
        start = np.where((start < last) & (start + 0.5 < lo), start + 1, start)  # column start is outside
        end = np.minimum(np.maximum(np.floor(hi - 0.5) + 1, first), last).astype(np.int64)
        end = np.where((end < last) & (end + 0.5 <= hi), end + 1, end)  # column end is inside
        end = np.where((end > first) & (end - 0.5 > hi), end - 1, end)  # column end-1 is outside
        widths = np.maximum(end - start, 0)
        span = np.repeat(np.arange(len(row_face)), widths)
        column = np.arange(len(span)) - np.repeat(np.cumsum(widths) - widths, widths) + start[span]
        return row[span] * self.width + column, face[span]

def _boxes(u_min: np.ndarray, u_max: np.ndarray, v_min: np.ndarray, v_max: np.ndarray, cam: Camera) -> np.ndarray:
    """Pixel boxes ``max(floor(min), 0)``..``min(ceil(max), size)`` of each polygon (clipped so that an empty
    box stays empty and fits in an int)."""
    return np.stack([np.clip(np.floor(u_min), 0, cam.width + 1), np.clip(np.ceil(u_max), -1, cam.width),
                     np.clip(np.floor(v_min), 0, cam.height + 1), np.clip(np.ceil(v_max), -1, cam.height)],
                    axis=1).astype(np.int64)


def _box_cells(box: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(index into ``faces``, row, column) of every pixel in each face's box, face by face, row-major."""
    u0, u1, v0, v1 = box[faces].T
    widths, heights = u1 - u0, v1 - v0
    cells = widths * heights
    owner = np.repeat(np.arange(len(faces)), cells)
    local = np.arange(int(cells.sum())) - np.repeat(np.cumsum(cells) - cells, cells)
    w = widths[owner]
    return owner, v0[owner] + local // w, u0[owner] + local % w


def _paint_last(flat: np.ndarray, pixels: np.ndarray, owners: np.ndarray, colours: np.ndarray) -> None:
    """Paint each of ``pixels`` with the colour of the last (highest) of its ``owners``: painter's order."""
    if len(pixels):
        winner = np.full(len(flat), -1, dtype=np.int64)
        np.maximum.at(winner, pixels, owners)
        painted = np.flatnonzero(winner >= 0)
        flat[painted] = colours[winner[painted]]


def _clip_near(polygon: np.ndarray, near: float) -> np.ndarray:
    """Sutherland–Hodgman clipping of a camera-frame polygon against the plane depth = ``near``."""
    out = []
    count = len(polygon)
    for i in range(count):
        a, b = polygon[i], polygon[(i + 1) % count]
        a_in, b_in = a[2] >= near, b[2] >= near
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out) if out else np.zeros((0, 3))


def _fill_convex(image: np.ndarray, u: list[float], v: list[float], colour: np.ndarray,
                 at_least_one: bool = False) -> int:
    """Fill the convex polygon with vertices (u, v) in pixel coordinates: every pixel whose centre lies
    inside is painted. Returns the number of pixels painted. The renderer fills a frame's faces in one
    pass (:class:`_FaceList`) that paints exactly what calling this face by face would (tested).

    Each edge bounds the polygon's span on every pixel row from the left or from the right, so the
    inside test is one interval per row instead of one half-plane test per pixel and edge.
    """
    height, width = image.shape[:2]
    u0, u1 = max(math.floor(min(u)), 0), min(math.ceil(max(u)), width)
    v0, v1 = max(math.floor(min(v)), 0), min(math.ceil(max(v)), height)
    if u0 >= u1 or v0 >= v1:
        return 0
    count = len(u)
    area = sum(u[i] * v[(i + 1) % count] - u[(i + 1) % count] * v[i] for i in range(count))
    painted = 0
    if abs(area) > 1e-12 and (u1 - u0) * (v1 - v0) <= _SMALL_BOX:
        painted = _fill_small(image, u, v, 1.0 if area > 0 else -1.0, (u0, u1, v0, v1), colour)
    elif abs(area) > 1e-12:
        sign = 1.0 if area > 0 else -1.0
        rows = _PIXEL_CENTRES[v0:v1]
        lo = np.full(v1 - v0, -np.inf)
        hi = np.full(v1 - v0, np.inf)
        for i in range(count):
            au, av, bu, bv = u[i], v[i], u[(i + 1) % count], v[(i + 1) % count]
            # Inside when k * u + c >= 0 on a row at height `rows`.
            k = -sign * (bv - av)
            c = sign * ((bu - au) * (rows - av) + (bv - av) * au)
            if k > 0.0:
                lo = np.maximum(lo, -c / k)
            elif k < 0.0:
                hi = np.minimum(hi, -c / k)
            else:
                hi = np.where(c < 0.0, -np.inf, hi)
        columns = _PIXEL_CENTRES[u0:u1]
        inside = (columns >= lo[:, None]) & (columns <= hi[:, None])
        painted = int(np.count_nonzero(inside))
        if painted:
            image[v0:v1, u0:u1][inside] = colour
    centroid_u, centroid_v = sum(u) / count, sum(v) / count
    coverage = abs(area) / 2
    if not painted and coverage < 1.0 and 0 <= centroid_u < width and 0 <= centroid_v < height:
        # A face smaller than a pixel can fall between pixel centres: a real sensor still sees it, as a
        # pixel partly covered. Blend it into the pixel under its centroid by the area it covers
        # (a lit lamp outshines the rest of its pixel).
        coverage = 1.0 if at_least_one else coverage
        cu, cv = int(centroid_u), int(centroid_v)
        blended = image[cv, cu] * (1.0 - coverage) + np.asarray(colour, dtype=float) * coverage
        image[cv, cu] = _to_uint8(blended) if image.dtype == np.uint8 else blended
        painted = 1
    return painted


_PIXEL_CENTRES = np.arange(8192) + 0.5
_SMALL_BOX = 16


def _fill_small(image: np.ndarray, u: list[float], v: list[float], sign: float, box: tuple[int, int, int, int],
                colour: np.ndarray) -> int:
    """The same inside test as :func:`_fill_convex`, pixel by pixel: far cheaper for a few pixels."""
    u0, u1, v0, v1 = box
    count = len(u)
    edges = [(u[i], v[i], u[(i + 1) % count] - u[i], v[(i + 1) % count] - v[i]) for i in range(count)]
    painted = 0
    for row in range(v0, v1):
        pv = row + 0.5
        for col in range(u0, u1):
            pu = col + 0.5
            if all(sign * (du * (pv - av) - dv * (pu - au)) >= 0.0 for au, av, du, dv in edges):
                image[row, col] = colour
                painted += 1
    return painted


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(values) + 0.5, 0, 255).astype(np.uint8)


# -- appearance of each kind ---------------------------------------------------------------------------


def _offset(x: float, y: float, yaw: float, forward: float, left: float = 0.0) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * forward - s * left, y + s * forward + c * left


def solids_for_actor(actor: Actor) -> list[Solid]:
    """The boxes an actor is drawn with, bottom to top (the order they are painted in)."""
    x, y, yaw, ln, wd, h = actor.x, actor.y, actor.yaw, actor.length, actor.width, actor.height
    if actor.kind == "pedestrian":
        return [
            Solid(x, y, yaw, ln * 0.6, wd * 0.7, 0.0, h * 0.49, (44, 48, 74)),
            Solid(x, y, yaw, ln, wd, h * 0.49, h * 0.86, (176, 48, 44)),
            Solid(x, y, yaw, ln * 0.5, wd * 0.4, h * 0.86, h, (226, 186, 150)),
        ]
    if actor.kind == "car":
        cx, cy = _offset(x, y, yaw, -0.08 * ln)
        return [
            Solid(x, y, yaw, ln * 0.82, wd * 0.96, 0.0, h * 0.22, (24, 24, 26)),
            Solid(x, y, yaw, ln, wd, h * 0.22, h * 0.6, (58, 92, 168)),
            Solid(cx, cy, yaw, ln * 0.55, wd * 0.9, h * 0.6, h, (62, 74, 92)),
        ]
    if actor.kind == "animal":
        return [
            Solid(x, y, yaw, ln * 0.7, wd * 0.6, 0.0, h * 0.4, (70, 52, 36)),
            Solid(x, y, yaw, ln, wd, h * 0.4, h, (128, 92, 58)),
        ]
    if actor.kind == "traffic_light":
        return _light_solids(actor)
    if actor.kind == "stop_sign":
        return _stop_sign_solids(actor)
    return [Solid(x, y, yaw, ln, wd, 0.0, h, (200, 0, 200))]


def _light_solids(actor: Actor) -> list[Solid]:
    x, y, yaw, h = actor.x, actor.y, actor.yaw, actor.height
    bottom = h - LIGHT_HEAD_HEIGHT
    px, py = _offset(x, y, yaw, -actor.length / 2 - 0.1)
    solids = [
        Solid(px, py, yaw, 0.16, 0.16, 0.0, h, (88, 90, 92)),
        Solid(x, y, yaw, actor.length, actor.width, bottom, h, (28, 30, 30)),
    ]
    lamp = min(actor.width * 0.7, LIGHT_HEAD_HEIGHT / 3 * 0.8)
    lx, ly = _offset(x, y, yaw, actor.length / 2 + 0.03)
    lamps = []
    for i, colour in enumerate(LAMP_ORDER):
        centre = h - LIGHT_HEAD_HEIGHT * (i + 0.5) / 3
        lit = actor.state == colour
        lamps.append(Solid(lx, ly, yaw, 0.06, lamp, centre - lamp / 2, centre + lamp / 2,
                           LAMP_COLOURS[colour] if lit else LAMP_OFF[colour], emissive=lit, front_only=True))
    return solids + sorted(lamps, key=lambda solid: solid.emissive)  # the lit lamp last: it outshines


def _stop_sign_solids(actor: Actor) -> list[Solid]:
    x, y, yaw, h = actor.x, actor.y, actor.yaw, actor.height
    bottom = h - SIGN_PLATE_SIZE
    px, py = _offset(x, y, yaw, -0.06)
    bx, by = _offset(x, y, yaw, 0.03)
    return [
        Solid(px, py, yaw, 0.07, 0.07, 0.0, bottom + 0.1, (150, 150, 150)),
        Solid(px, py, yaw, 0.04, SIGN_PLATE_SIZE, bottom, h, (140, 140, 140)),
        Solid(x, y, yaw, 0.04, SIGN_PLATE_SIZE, bottom, h, (196, 22, 26), emissive=True, front_only=True),
        Solid(bx, by, yaw, 0.02, SIGN_PLATE_SIZE * 0.7, bottom + SIGN_PLATE_SIZE * 0.4,
              bottom + SIGN_PLATE_SIZE * 0.6, (240, 240, 240), front_only=True),
    ]


def solids_for_prop(prop: Prop, index: int) -> list[Solid]:
    palette = PROP_COLOURS.get(prop.kind, ((128, 128, 128),))
    colour = palette[index % len(palette)]
    if prop.kind == "tree":
        return [
            Solid(prop.x, prop.y, prop.yaw, 0.35, 0.35, 0.0, prop.height * 0.4, (92, 66, 40)),
            Solid(prop.x, prop.y, prop.yaw, prop.length, prop.width, prop.height * 0.4, prop.height, colour),
        ]
    return [Solid(prop.x, prop.y, prop.yaw, prop.length, prop.width, 0.0, prop.height, colour)]


def count_pixels_differing(a: np.ndarray, b: np.ndarray) -> int:
    """How many pixels differ between two images (any channel): an object's rendered footprint."""
    return int(np.any(a != b, axis=-1).sum())
