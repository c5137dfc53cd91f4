"""The open hand's signed distance field: rigid parts per bone, a smooth union, and fine detail.

Every part is defined in the rest pose and attached to one bone ``j`` (:mod:`.parts`); a query
point ``x`` is taken into the bone's rest frame with ``x_j = A_j^-1 x`` (``A_j`` = rest-to-posed
transform of :func:`lisa_hand.skeleton.forward_kinematics`), so parts move rigidly with their
bones:

- round cones (hulls of two spheres) along each phalanx, their axes a little palmar of the bone
  so that the back of a flexed joint shows a knuckle, plus lateral capsules for the condyles at
  the PIP/DIP/IP joints and the metacarpal heads (the knuckles of a fist);
- a palm body (a rounded convex slab spanning a short forearm stub, the wrist and the four MCP
  joints), the hypothenar pad, the finger webs, the first web space and the thumb's metacarpal
  with the thenar eminence, blended with a wide radius (``blend_palm``, about 3.5 mm) into one
  soft body;
- everything joined by a smooth minimum ``s = -k log sum_i exp(-d_i / k)`` (``k = blend``, about
  1.2 mm). Because the parts of two bones move rigidly and blend, a flexed joint bulges on the
  outside and creases on the inside: pose-dependent deformation that linear blend skinning of a
  template cannot represent.

Fine detail (:mod:`.detail`) is added as small displacements: flexion creases, dorsal knuckle
wrinkles, palm lines, raised fingernails and per-subject bumps of about 0.1-0.2 mm. Near the
surface ``|grad s|`` is 1 (to 5 %) on about 80 % of an open hand; it dips below 1 inside the
blends (part junctions, contacts between fingers) where the smooth union slightly
under-estimates the distance. Skinning weights are the union's blend factors ``softmax(-d / k)``
summed per bone (the derivatives of ``s`` with respect to each part's distance), so they sum to
1 and say which bones own a point.

Speed: each part, crease and nail has a rest-pose local frame; posing composes it with
``A_j^-1`` into one affine map, so local coordinates of all parts come from one small matrix
product, and :class:`PosedField` groups query points into cells of a few centimetres and drops the
parts, creases and nails that cannot reach a cell (their blend weight there is below
``exp(-10)``; :mod:`.culling`).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch

from ..geometry.transforms import invert_rigid
from ..skeleton.tree import NUM_JOINTS, PARENTS
from ..utils.threads import cpu_threads
from .culling import group_in_cells, reachable_parts
from .detail import bumps_at, creases_at, nails_at, palm_lines_at
from .parts import HandParts, local_coordinates, posed_frame_maps
from .primitives import gaussian, smooth_union, smoothstep

__all__ = ["HandFieldOutput", "PosedField", "single_threaded"]

# Points evaluated together at most (keeps temporaries in cache), fewest points worth culling.
_MAX_GROUP = 8192
_MIN_CULL = 2048


@dataclass
class HandFieldOutput:
    """The hand's field at N query points (world frame).

    sdf: [N] signed distance, metres (negative inside).
    weights: [N, 16] skinning weights (bone ownership), rows summing to 1.
    rest_points: [N, 3] the points carried back to the rest pose by their owning bones
        (``sum_j w_j A_j^-1 x``), metres: what texture and appearance are functions of.
    nail: [N] in [0, 1], 1 on a fingernail. nail_along: [N] in [0, 1], cuticle to free edge.
    crease: [N] in [0, 1], 1 in the middle of a crease, palm line or knuckle wrinkle.
    palmar: [N] in [0, 1], 1 on the palmar side.
    knuckle: [N] in [0, 1], 1 on the back of a knuckle.
    Feature fields (``rest_points`` onward) are None unless requested.
    """

    sdf: torch.Tensor
    weights: torch.Tensor
    rest_points: torch.Tensor | None = None
    nail: torch.Tensor | None = None
    nail_along: torch.Tensor | None = None
    crease: torch.Tensor | None = None
    palmar: torch.Tensor | None = None
    knuckle: torch.Tensor | None = None


def _plus(total: torch.Tensor | None, term: torch.Tensor) -> torch.Tensor:
    return term if total is None else total + term


@contextlib.contextmanager
def single_threaded(device: torch.device | str) -> Iterator[None]:
    """Run CPU tensor work on one thread (:func:`lisa_hand.utils.threads.cpu_threads`, restored
    afterwards); no-op on other devices.

    The field is many small tensor operations: intra-op threads do not pay for their start-up,
    and when other processes share the cores OpenMP's spinning makes them ten times slower.
    """
    if torch.device(device).type != "cpu":
        yield
        return
    with cpu_threads(1):
        yield


@dataclass
class _Selection:
    """Indices of the parts, creases, nails and palm lines evaluated for a group of points."""

    cones: torch.Tensor
    slabs: list[int]
    creases: torch.Tensor
    nails: torch.Tensor
    lines: bool


@dataclass
class _Prepared:
    """A selection's gathered frames (one matrix product gives all local coordinates) and
    parameter rows; local frame order: cones (palm group first), creases, nails, plane, bone 0."""

    weight: torch.Tensor
    bias: torch.Tensor
    count: int
    num_cones: int
    num_palm: int
    palm_on: bool
    cone_table: torch.Tensor
    palm_onehot: torch.Tensor | None
    top_onehot: torch.Tensor
    num_creases: int
    crease_table: torch.Tensor
    crease_owner: torch.Tensor
    num_nails: int
    nail_index: torch.Tensor
    nail_owner: torch.Tensor
    lines: bool


@dataclass
class _Detail:
    """The detail of one group of points: its displacement [N] (metres) and what the appearance
    features are made of (None where the group has none of that detail)."""

    displacement: torch.Tensor
    rest_points: torch.Tensor
    x_palm: torch.Tensor
    crease_shape: torch.Tensor | None
    line_shape: torch.Tensor | None
    nail_mask: torch.Tensor | None
    nail_along: torch.Tensor | None


class PosedField:
    """The signed distance field (and features) of one subject in one pose.

    parts: the subject's :class:`~lisa_hand.handmodel.parts.HandParts` (any device/dtype:
        converted to ``dtype`` on the transforms' device).
    transforms: [16, 4, 4] rest-to-posed bone transforms ``A_j`` (world frame, metres).
    cell_size: edge of the cells that group query points for culling, metres.
    """

    def __init__(self, parts: HandParts, transforms: torch.Tensor, cell_size: float = 0.02) -> None:
        if transforms.shape != (NUM_JOINTS, 4, 4):
            raise ValueError(f"transforms must be [16, 4, 4], got {tuple(transforms.shape)}")
        self.dtype = transforms.dtype
        self.device = transforms.device
        self.parts = parts.to(self.device, self.dtype)
        self.cell_size = cell_size
        self.transforms = transforms
        self.inv_transforms = invert_rigid(transforms)
        self._init_maps()
        self._init_ownership()
        self._init_bounds()
        tpl = self.parts
        self.all_cones = torch.arange(tpl.cone_bone.shape[0], device=self.device)
        self.all_creases = torch.arange(tpl.crease_bone.shape[0], device=self.device)
        self.all_nails = torch.arange(5, device=self.device)
        self._everything = _Selection(
            self.all_cones, list(range(len(tpl.slab_vertices))), self.all_creases,
            self.all_nails, True,
        )  # fmt: skip
        self._init_tables()
        self._prepared: dict[tuple, _Prepared] = {}

    def _init_maps(self) -> None:
        """World -> local affine maps of every bone, part, crease and nail frame."""
        tpl, inv = self.parts, self.inv_transforms
        skel = tpl.skeleton
        identity = torch.eye(3, dtype=self.dtype, device=self.device)
        bones = torch.arange(NUM_JOINTS, device=self.device)
        # world -> each bone's rest frame (for rest points), and bone-anatomical frames.
        self.rest_matrix, self.rest_offset = inv[:, :3, :3], inv[:, :3, 3]
        bone_rot = torch.stack([skel.bone_dirs, skel.dorsal, skel.lateral], dim=1)
        self.bone_matrix, self.bone_offset = posed_frame_maps(bone_rot, skel.joints, bones, inv)
        self.cone_matrix, self.cone_offset = posed_frame_maps(
            tpl.cone_rot, tpl.cone_origin, tpl.cone_bone, inv
        )
        self.slab_matrix, self.slab_offset = posed_frame_maps(
            tpl.slab_rot, tpl.slab_origin, tpl.slab_bone, inv
        )
        self.crease_matrix, self.crease_offset = posed_frame_maps(
            tpl.crease_rot, tpl.crease_origin, tpl.crease_bone, inv
        )
        self.nail_matrix, self.nail_offset = posed_frame_maps(
            tpl.nail_rot, tpl.nail_origin, tpl.nail_bone, inv
        )
        self.palm_matrix, self.palm_offset = posed_frame_maps(
            identity[None], torch.zeros_like(identity[:1]), bones[:1], inv
        )
        self.rest_flat = inv[:, :3, :3].reshape(NUM_JOINTS, 9)

    def _init_ownership(self) -> None:
        """One-hot part -> bone maps for ownership, and bone -> detail ownership selectors."""
        tpl = self.parts

        def onehot(index: torch.Tensor) -> torch.Tensor:
            return torch.nn.functional.one_hot(index, NUM_JOINTS).to(self.dtype)

        self.cone_onehot = onehot(tpl.cone_bone)
        self.slab_onehot = onehot(tpl.slab_bone)
        same = (tpl.crease_parent == tpl.crease_bone)[:, None]
        self.crease_owner = (
            onehot(tpl.crease_bone) + onehot(tpl.crease_parent).masked_fill(same, 0.0)
        ).T.contiguous()  # [16, C]
        self.nail_owner = onehot(tpl.nail_bone).T.contiguous()  # [16, 5]
        palmar = tpl.crease_side > 0
        self.crease_face_low = torch.where(palmar, -0.05, 0.35).to(self.dtype)
        self.crease_face_high = torch.where(palmar, 0.5, 0.8).to(self.dtype)

    def _init_bounds(self) -> None:
        """Posed bounding spheres' centres (the radii are the rest-pose ones)."""
        tpl, transforms = self.parts, self.transforms
        bones = torch.arange(NUM_JOINTS, device=self.device)

        def posed(center: torch.Tensor, bone: torch.Tensor) -> torch.Tensor:
            a = transforms[bone]
            return (a[:, :3, :3] @ center[..., None])[..., 0] + a[:, :3, 3]

        self.cone_center = posed(tpl.cone_center, tpl.cone_bone)
        self.slab_center = posed(tpl.slab_center, tpl.slab_bone)
        self.crease_center = posed(tpl.crease_origin, tpl.crease_bone)
        self.nail_center = posed(tpl.nail_center, tpl.nail_bone)
        self.line_center = posed(tpl.line_bound_center, bones[:1].expand(len(tpl.line_bound)))

    def _init_tables(self) -> None:
        """Stacked frames and per-part parameter rows for the hot path (:meth:`_evaluate`)."""
        tpl = self.parts
        # All local frames in one table: cones, creases, nails, the slabs' plane, bone 0.
        plane_matrix, plane_offset = posed_frame_maps(
            tpl.slab_rot[:1], torch.zeros_like(tpl.slab_origin[:1]), tpl.slab_bone[:1],
            self.inv_transforms,
        )  # fmt: skip
        matrices = [self.cone_matrix, self.crease_matrix, self.nail_matrix, plane_matrix,
                    self.palm_matrix]  # fmt: skip
        offsets = [self.cone_offset, self.crease_offset, self.nail_offset, plane_offset,
                   self.palm_offset]  # fmt: skip
        self.frame_matrix = torch.cat(matrices)  # [K, 3, 3]
        self.frame_offset = torch.cat(offsets)  # [K, 3]
        num_cones, num_creases = tpl.cone_bone.shape[0], tpl.crease_bone.shape[0]
        self.crease_start = num_cones
        self.nail_start = num_cones + num_creases
        self.plane_index = self.nail_start + 5
        # Cone rows: length, start radius, sin a, tan a.
        sin_a = (tpl.cone_radii[:, 0] - tpl.cone_radii[:, 1]) / tpl.cone_length
        tan_a = sin_a / (1.0 - sin_a * sin_a).sqrt()
        self.cone_table = torch.stack([tpl.cone_length, tpl.cone_radii[:, 0], sin_a, tan_a], 1)
        # Crease rows: 1 / width, depth, -side / radius, face low, face high, near far, near in.
        self.crease_table = torch.stack(
            [1.0 / tpl.crease_width, tpl.crease_depth, -tpl.crease_side / tpl.crease_radius,
             self.crease_face_low, self.crease_face_high, tpl.crease_radius + 0.006,
             tpl.crease_radius + 0.0025], 1,
        )  # fmt: skip
        # Slabs: both planes share their axes; edges padded to the same count.
        num_vertices = max(v.shape[0] for v in tpl.slab_vertices)
        padded = [
            torch.cat([v, v[-1:].expand(num_vertices - v.shape[0], 2)]) for v in tpl.slab_vertices
        ]
        vertices = torch.stack(padded)  # [Q, V, 2]
        edges = torch.roll(vertices, -1, dims=1) - vertices
        self.slab_vx, self.slab_vy = vertices[..., 0].reshape(-1), vertices[..., 1].reshape(-1)
        self.slab_ex, self.slab_ey = edges[..., 0].reshape(-1), edges[..., 1].reshape(-1)
        self.slab_inv_len = 1.0 / (edges * edges).sum(-1).clamp_min(1e-20).reshape(-1)
        self.slab_height = tpl.slab_origin @ tpl.slab_rot[0, 2]  # plane heights along normal
        self.slab_shape = (vertices.shape[0], num_vertices)

    def _prepare(self, sel: _Selection) -> _Prepared:
        """Gather the frames and parameters of a selection once (cached by its indices)."""
        key = (tuple(sel.cones.tolist()), tuple(sel.slabs), tuple(sel.creases.tolist()),
               tuple(sel.nails.tolist()), sel.lines)  # fmt: skip
        prepared = self._prepared.get(key)
        if prepared is not None:
            return prepared
        tpl = self.parts
        palm_flags = tpl.cone_palm[sel.cones]
        cones = torch.cat([sel.cones[palm_flags], sel.cones[~palm_flags]])
        num_palm = int(palm_flags.sum())
        palm_on = bool(sel.slabs) or num_palm > 0
        frames = torch.cat(
            [cones, self.crease_start + sel.creases, self.nail_start + sel.nails,
             torch.tensor([self.plane_index, self.plane_index + 1], device=self.device)]
        )  # fmt: skip
        matrix = self.frame_matrix[frames]
        count = frames.shape[0]
        weight = matrix.transpose(0, 1).reshape(3 * count, 3).T.contiguous()
        bias = self.frame_offset[frames].T.reshape(3 * count).contiguous()
        onehot = self.cone_onehot[cones]
        palm_onehot = torch.cat([onehot[:num_palm], self.slab_onehot]) if palm_on else None
        prepared = _Prepared(
            weight=weight,
            bias=bias,
            count=count,
            num_cones=cones.shape[0],
            num_palm=num_palm,
            palm_on=palm_on,
            cone_table=self.cone_table[cones],
            palm_onehot=palm_onehot,
            top_onehot=onehot[num_palm:],
            num_creases=sel.creases.shape[0],
            crease_table=self.crease_table[sel.creases],
            crease_owner=self.crease_owner[:, sel.creases],
            num_nails=sel.nails.shape[0],
            nail_index=sel.nails,
            nail_owner=self.nail_owner[:, sel.nails],
            lines=sel.lines and palm_on,
        )
        self._prepared[key] = prepared
        return prepared

    # ------------------------------------------------------------------------------------------
    def evaluate(
        self, points: torch.Tensor, with_features: bool = False, cull: bool = True
    ) -> HandFieldOutput:
        """The field at world points.

        points: [N, 3] world points, metres, on this field's device (any float dtype; computed
            in the field's dtype).
        with_features: also compute rest points and appearance features.
        cull: group points in cells and skip the parts that cannot reach a cell (same values to
            about 1e-7 m); False evaluates every part at every point (the reference).
        """
        points = points.to(self.dtype)
        with single_threaded(points.device):
            return self._evaluate_grouped(points, with_features, cull)

    def _evaluate_grouped(
        self, points: torch.Tensor, with_features: bool, cull: bool
    ) -> HandFieldOutput:
        num = points.shape[0]
        if not cull or num <= _MIN_CULL:
            return self._evaluate(points, self._everything, with_features)
        order, counts, centers, cell = group_in_cells(points, self.cell_size)
        masks = reachable_parts(self, centers, 0.5 * math.sqrt(3.0) * cell)
        pieces: list[HandFieldOutput] = []
        for m, index in enumerate(torch.split(order, counts.tolist())):
            selection = _Selection(
                torch.nonzero(masks[0][m])[:, 0],
                [q for q in range(masks[1].shape[1]) if masks[1][m, q]],
                torch.nonzero(masks[2][m])[:, 0],
                torch.nonzero(masks[3][m])[:, 0],
                bool(masks[4][m]),
            )
            group = points[index]
            for begin in range(0, group.shape[0], _MAX_GROUP):
                pieces.append(
                    self._evaluate(group[begin : begin + _MAX_GROUP], selection, with_features)
                )
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(num, device=order.device)
        merged = {}
        for name in HandFieldOutput.__dataclass_fields__:
            values = [getattr(piece, name) for piece in pieces]
            merged[name] = None if values[0] is None else torch.cat(values)[inverse]
        return HandFieldOutput(**merged)

    # ------------------------------------------------------------------------------------------
    # The hot path: one group of points and its selection of parts

    def _evaluate(
        self, points: torch.Tensor, sel: _Selection, with_features: bool
    ) -> HandFieldOutput:
        prep = self._prepare(sel)
        count = prep.count
        local = torch.addmm(prep.bias, points, prep.weight)  # [N, 3K]: all along | up | side
        along, up, side = local[:, :count], local[:, count : 2 * count], local[:, 2 * count :]
        sdf, weights = self._union(along, up, side, prep)
        detail = self._detail(points, along, up, side, weights, prep)
        sdf = sdf + detail.displacement
        if not with_features:
            return HandFieldOutput(sdf=sdf, weights=weights)
        return self._features(points, sdf, weights, detail, prep)

    def _union(
        self, along: torch.Tensor, up: torch.Tensor, side: torch.Tensor, prep: _Prepared
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Smooth union of the selected parts -> (sdf [N] metres, weights [N, 16])."""
        tpl = self.parts
        k, count = prep.num_cones, prep.count
        # Round cones (branch-free form of primitives.round_cone_sdf with cached rows).
        table = prep.cone_table
        c_along, c_up, c_side = along[:, :k], up[:, :k], side[:, :k]
        radial_sq = c_up * c_up + c_side * c_side
        radial = (radial_sq + 1e-20).sqrt()
        center = torch.minimum((c_along - radial * table[:, 3]).clamp_min(0.0), table[:, 0])
        offset = c_along - center
        cone_d = (offset * offset + radial_sq + 1e-20).sqrt() - (table[:, 1] - center * table[:, 2])
        if not prep.palm_on:
            sdf, top_w = smooth_union(cone_d, tpl.blend)
            return sdf, top_w @ prep.top_onehot
        # Palm group: palm cones and the rounded slabs (shared plane axes).
        plane = slice(count - 2, count - 1)
        slab_d = self._slab_distances(along[:, plane], up[:, plane], side[:, plane])
        palm_d = torch.cat([cone_d[:, : prep.num_palm], slab_d], dim=1)
        palm_s, palm_w = smooth_union(palm_d, tpl.blend_palm)
        top_d = torch.cat([palm_s[:, None], cone_d[:, prep.num_palm :]], dim=1)
        sdf, top_w = smooth_union(top_d, tpl.blend)
        weights = (top_w[:, :1] * palm_w) @ prep.palm_onehot + top_w[:, 1:] @ prep.top_onehot
        return sdf, weights

    def _slab_distances(
        self, plane_a: torch.Tensor, plane_b: torch.Tensor, height: torch.Tensor
    ) -> torch.Tensor:
        """Rounded slabs' distances [N, Q] from plane coordinates [N, 1] each (a, b, height)."""
        rel_x, rel_y = plane_a - self.slab_vx, plane_b - self.slab_vy  # [N, Q V]
        t = ((rel_x * self.slab_ex + rel_y * self.slab_ey) * self.slab_inv_len).clamp(0, 1)
        dx, dy = rel_x - t * self.slab_ex, rel_y - t * self.slab_ey
        shape = (plane_a.shape[0],) + self.slab_shape
        seg_sq = (dx * dx + dy * dy).view(shape).amin(-1)  # [N, Q]
        cross = (self.slab_ex * rel_y - self.slab_ey * rel_x).view(shape).amin(-1)
        outside = (cross < 0.0).to(plane_a.dtype)
        heights = height - self.slab_height
        return (seg_sq * outside + heights * heights + 1e-20).sqrt() - self.parts.slab_radius

    def _detail(
        self,
        points: torch.Tensor,
        along: torch.Tensor,
        up: torch.Tensor,
        side: torch.Tensor,
        weights: torch.Tensor,
        prep: _Prepared,
    ) -> _Detail:
        """Creases, palm lines, nails and bumps of the selection (see :mod:`.detail`)."""
        tpl = self.parts
        k = prep.num_cones
        displacement = None
        crease_shape = None
        if prep.num_creases:
            lo, hi = k, k + prep.num_creases
            crease_shape, creases = creases_at(along[:, lo:hi], up[:, lo:hi], side[:, lo:hi],
                                               prep.crease_table, prep.crease_owner, weights)
            displacement = creases
        x_palm = torch.stack([along[:, -1], up[:, -1], side[:, -1]], dim=1)
        line_shape = None
        if prep.lines:
            line_shape, lines = palm_lines_at(x_palm, weights, tpl)
            displacement = _plus(displacement, lines)
        nail_mask = None
        nail_along = None
        if prep.num_nails:
            lo = k + prep.num_creases
            hi = lo + prep.num_nails
            nail_along = along[:, lo:hi]
            nail_mask, nails = nails_at(nail_along, up[:, lo:hi], side[:, lo:hi],
                                        prep.nail_index, weights @ prep.nail_owner, tpl)
            displacement = _plus(displacement, nails)
        # Bumps at the rest-pose point, carried by the owning bones:
        # sum_j w_j (R_j x + t_j) = (sum_j w_j R_j) x + sum_j w_j t_j.
        blended = (weights @ self.rest_flat).view(points.shape[0], 3, 3)
        rest_points = (blended @ points[:, :, None])[..., 0] + weights @ self.rest_offset
        displacement = _plus(displacement, bumps_at(rest_points, tpl))
        return _Detail(displacement=displacement, rest_points=rest_points, x_palm=x_palm,
                       crease_shape=crease_shape, line_shape=line_shape, nail_mask=nail_mask,
                       nail_along=nail_along)  # fmt: skip

    def _features(
        self,
        points: torch.Tensor,
        sdf: torch.Tensor,
        weights: torch.Tensor,
        detail: _Detail,
        prep: _Prepared,
    ) -> HandFieldOutput:
        """The appearance features (nail, crease, palmar, knuckle) of :class:`HandFieldOutput`."""
        tpl = self.parts
        zeros = sdf.new_zeros(sdf.shape)
        if detail.nail_mask is not None:
            n = prep.nail_index
            span = (tpl.nail_end[n] - tpl.nail_start[n]).clamp_min(1e-6)
            along = ((detail.nail_along - tpl.nail_start[n]) / span).clamp(0.0, 1.0)
            total = detail.nail_mask.sum(-1)
            nail = total.clamp(max=1.0)
            nail_along = (along * detail.nail_mask).sum(-1) / total.clamp_min(1e-6)
        else:
            nail, nail_along = zeros, zeros
        crease = zeros
        if detail.crease_shape is not None:
            crease = torch.maximum(crease, detail.crease_shape.amax(-1))
        if detail.line_shape is not None:
            crease = torch.maximum(crease, detail.line_shape.amax(-1))
        crease = crease.clamp(max=1.0)
        palmar, knuckle = self._palmar_and_knuckle(points, weights, detail.x_palm)
        return HandFieldOutput(
            sdf=sdf,
            weights=weights,
            rest_points=detail.rest_points,
            nail=nail,
            nail_along=nail_along,
            crease=crease,
            palmar=palmar,
            knuckle=knuckle,
        )

    def _palmar_and_knuckle(
        self, points: torch.Tensor, weights: torch.Tensor, x_palm: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(palmar [N], knuckle [N]) in [0, 1] (see :class:`HandFieldOutput`)."""
        tpl = self.parts
        skel = tpl.skeleton
        # Palmar side: for fingers from the bone-local dorsal coordinate, for the palm from height.
        along, up, _ = local_coordinates(points, self.bone_matrix, self.bone_offset)  # [N, 16] each
        bone_radius = skel.radii.mean(-1)
        finger_palmar = smoothstep(0.15 * bone_radius, -0.45 * bone_radius, up)
        palm_y, half = tpl.palm_center_y, tpl.palm_half_thickness
        palm_palmar = smoothstep(palm_y + 0.1 * half, palm_y - 0.6 * half, x_palm[:, 1])
        finger_palmar = torch.cat([palm_palmar[:, None], finger_palmar[:, 1:]], dim=1)
        palmar = (weights * finger_palmar).sum(-1)
        # Knuckles: the back of each joint, where the joint's two bones own the surface.
        joint_near = gaussian(along / (0.6 * bone_radius))
        back = smoothstep(0.2 * bone_radius, 0.8 * bone_radius, up)
        parents = torch.as_tensor(PARENTS[1:], device=points.device)
        joint_owner = (weights[:, 1:] + weights[:, parents]).clamp(max=1.0)
        knuckle = (joint_near[:, 1:] * back[:, 1:] * joint_owner).amax(-1)
        return palmar, knuckle
