"""Free space of a one-view scan: where a depth sensor saw nothing.

A sensor at ``viewpoint`` that returned the point ``x`` saw through the segment from itself to
``x``, and where it returned nothing (pixels around the hand with no point) it saw through the
whole ray. So a hand fitted to a one-view scan must not put surface there: a finger left straight
where the real one curls away out of sight can fit every scan point, yet the sensor would have
seen it. A full (many-view) scan has no single viewpoint and gets none of this.

* :class:`DepthImage`: the scan seen from its sensor (gnomonic projection about the mean viewing
  direction, ``pixel_m`` pixels at the mean range, occupied pixels dilated by ``dilate_px`` so
  that gaps between sparse points stay unknown, ``border_m`` of empty image around), and how far
  a point lies in the free space (:meth:`DepthImage.violation`, differentiable): the proxy
  stages' free-space term (:mod:`.proxy`).
* :func:`free_space_points`: empty points spread over the view, *in front* (on the ray of a scan
  point, ``margin_m`` to ``depth_m`` before it) and *beside* (on rays through empty pixels,
  between ``depth_m`` before the nearest return and beyond the farthest);
  :func:`free_points_near`: empty points near a candidate hand's surface, where a wrong hand is.
* :meth:`DepthImage.could_see`: whether the sensor could have returned a surface point (facing
  it, not hidden behind what it returned): the proxy stages ask coverage only of those, and a
  finger with little such surface counts as unseen (:func:`.proxy.unseen_fingers`).
  The surface stage asks the field to be outside at both (:mod:`.surface_stage`).

``FitPointsConfig.free_space_weight`` weighs the terms; ``fit_points(viewpoint=...)`` (``lisa
fit-points --viewpoint``) turns them on.
"""

from __future__ import annotations

import torch

__all__ = ["DepthImage", "free_space_points", "free_points_near"]


class DepthImage:
    """The scan's depth image seen from its sensor, to tell how far points lie in its free space.

    Pixels as in the module docstring. :meth:`violation` is 0 for a point behind the scan's
    nearest return at its pixel (or less than ``margin_m`` before it), the depth by which it
    lies before that return otherwise, and for a point on an empty pixel its distance across
    the image to the nearest occupied pixel (at its range), plus ``margin_m``.
    """

    def __init__(self, points: torch.Tensor, viewpoint: torch.Tensor, *,
                 margin_m: float = 0.003, pixel_m: float = 0.002, dilate_px: int = 2,
                 border_m: float = 0.03) -> None:
        """points: [N, 3] world metres (what the sensor returned); viewpoint: [3] world
        metres."""
        from scipy.ndimage import distance_transform_edt

        like = dict(device=points.device, dtype=points.dtype)
        self.viewpoint = viewpoint.to(**like)
        rays = points - self.viewpoint
        if not bool((rays.norm(dim=-1) > margin_m).all()):
            raise ValueError("viewpoint: the sensor position lies within the scan's points")
        self.axis, self.e1, self.e2 = _view_frame(rays)
        if not bool((rays @ self.axis > 0.2 * rays.norm(dim=-1)).all()):
            raise ValueError("viewpoint: the scan spans too wide an angle from the sensor "
                             "position to be one view of it")
        plane, ranges = self.project(points)
        self.pixel = pixel_m / float(ranges.mean())
        self.low = plane.amin(0) - border_m / float(ranges.mean())
        self.size = ((plane.amax(0) + border_m / float(ranges.mean()) - self.low)
                     / self.pixel).ceil().long() + 1
        cells = self.cells(plane)
        depth = torch.full((int(self.size[0]), int(self.size[1])), float("inf"), **like)
        flat = cells[:, 0] * depth.shape[1] + cells[:, 1]
        depth = depth.flatten().scatter_reduce(0, flat, ranges, "amin").reshape(depth.shape)
        occupied = torch.isfinite(depth)
        # the farthest return around each pixel (inf where there is none): what lies behind
        # it was hidden from the sensor (:meth:`could_see`)
        far = torch.nn.functional.max_pool2d(
            depth.masked_fill(~occupied, -1e6)[None, None], 2 * dilate_px + 1, stride=1,
            padding=dilate_px)[0, 0]
        self.far = far.masked_fill(far < -1e5, float("inf"))
        if dilate_px > 0:
            grown = -torch.nn.functional.max_pool2d(
                -depth.nan_to_num(posinf=1e6)[None, None], 2 * dilate_px + 1, stride=1,
                padding=dilate_px)[0, 0]
            occupied = grown < 1e5
            depth = torch.where(occupied, grown, depth)
        self.margin = margin_m
        self.depth = depth  # [W, H] metres, inf where empty
        # distance across the image to the nearest occupied pixel, in pixels
        gap = distance_transform_edt((~occupied).cpu().numpy())
        self.gap = torch.as_tensor(gap, **like)

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points [..., 3] world metres -> (gnomonic image coordinates [..., 2], ranges [...]
        metres from the sensor)."""
        rays = points - self.viewpoint
        along = (rays @ self.axis).clamp_min(1e-6)
        plane = torch.stack([rays @ self.e1, rays @ self.e2], dim=-1) / along[..., None]
        return plane, rays.norm(dim=-1)

    def cells(self, plane: torch.Tensor) -> torch.Tensor:
        """[..., 2] integer pixels of image coordinates (clamped into the image)."""
        cells = ((plane - self.low) / self.pixel).floor().long()
        return torch.minimum(cells.clamp_min(0), (self.size - 1).to(cells.device))

    def violation(self, points: torch.Tensor) -> torch.Tensor:
        """[...] metres: how far each point [..., 3] world metres lies in the free space
        (0 where the sensor could not have seen it; see the class docstring). Differentiable
        in the points."""
        plane, ranges = self.project(points)
        cells = self.cells(plane)
        depth = self.depth[cells[..., 0], cells[..., 1]]
        empty = ~torch.isfinite(depth)
        front = (depth.nan_to_num(posinf=0.0) - self.margin - ranges).clamp_min(0.0)
        # off the scan's image: the gap to the nearest occupied pixel (bilinear, so that it
        # pulls the point towards the scan), at the point's range
        index = (plane - self.low) / self.pixel - 0.5  # [..., 2] pixel-centre coordinates
        span = (self.size - 1).clamp_min(1).to(index)
        grid = (2.0 * index / span - 1.0).flip(-1).reshape(1, 1, -1, 2)
        gap = torch.nn.functional.grid_sample(self.gap[None, None], grid, mode="bilinear",
                                              padding_mode="border", align_corners=True)
        across = gap.reshape(ranges.shape) * self.pixel * ranges.detach() + self.margin
        return torch.where(empty, across, front)

    @torch.no_grad()
    def could_see(self, points: torch.Tensor, normals: torch.Tensor | None,
                  occluded_m: float = 0.005) -> torch.Tensor:
        """[...] float, 1 or 0: whether the sensor could have returned each point [..., 3]
        (world metres) with outward unit normals [..., 3] (None: every point faces it): it
        faces the sensor and lies no more than ``occluded_m`` behind the farthest of the scan's
        returns around its pixel (points where there are none count as seeable). A surface
        point that fails either test is one a one-view scan cannot show, so no scan point need
        be near it."""
        plane, ranges = self.project(points)
        cells = self.cells(plane)
        far = self.far[cells[..., 0], cells[..., 1]]
        seeable = ranges <= far + occluded_m  # inf (no return around): True
        if normals is not None:
            seeable = seeable & (((self.viewpoint - points) * normals).sum(-1) > 0)
        return seeable.to(points.dtype)


def _view_frame(rays: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(the mean viewing direction, two unit vectors across it) of rays [N, 3]."""
    like = dict(device=rays.device, dtype=rays.dtype)
    axis = (rays / rays.norm(dim=-1, keepdim=True)).mean(0)
    axis = axis / axis.norm()
    helper = torch.eye(3, **like)[int(torch.argmin(axis.abs()))]
    e1 = torch.linalg.cross(axis, helper)
    e1 = e1 / e1.norm()
    return axis, e1, torch.linalg.cross(axis, e1)


def free_space_points(
    image: DepthImage,
    points: torch.Tensor,
    count: int,
    generator: torch.Generator,
    *,
    depth_m: float = 0.02,
    beside_fraction: float = 0.5,
) -> torch.Tensor:
    """[count, 3] world metres: empty points of the one-view scan ``points`` (module docstring).

    image: the scan's :class:`DepthImage` (its sensor position and pixels). points: [N, 3]
    world metres, what the sensor returned. generator: a CPU generator (the samples are
    deterministic given it). depth_m: how far before a return (and beyond the farthest)
    samples go. beside_fraction: the share of the points drawn beside the scan (the rest in
    front of it); when no pixel around the scan is empty, all are in front.
    """
    like = dict(device=points.device, dtype=points.dtype)
    _, ranges = image.project(points)
    units = (points - image.viewpoint) / ranges[:, None]
    empty = (~torch.isfinite(image.depth)).nonzero()

    def uniform(num: int) -> torch.Tensor:
        return torch.rand(num, generator=generator).to(**like)

    beside = int(round(count * beside_fraction)) if empty.shape[0] > 0 else 0
    front = count - beside
    chosen = torch.randint(points.shape[0], (front,), generator=generator).to(points.device)
    back = image.margin + (depth_m - image.margin) * uniform(front)
    samples = [image.viewpoint + units[chosen] * (ranges[chosen] - back)[:, None]]
    if beside > 0:
        picked = empty[torch.randint(empty.shape[0], (beside,), generator=generator)
                       .to(points.device)]
        jitter = torch.stack([uniform(beside), uniform(beside)], dim=-1)
        coords = image.low + (picked.to(**like) + jitter) * image.pixel
        directions = image.axis + coords[:, :1] * image.e1 + coords[:, 1:] * image.e2
        directions = directions / directions.norm(dim=-1, keepdim=True)
        near = float(ranges.min()) - depth_m
        far = float(ranges.max()) + depth_m
        distance = near + (far - near) * uniform(beside)
        samples.append(image.viewpoint + directions * distance[:, None])
    return torch.cat(samples)


def free_points_near(depth: DepthImage, surface: torch.Tensor, count: int,
                     generator: torch.Generator, spread_m: float = 0.005) -> torch.Tensor:
    """[<= count, 3] world metres: points near a hand's surface that the sensor saw to be empty.

    surface: [P, 3] world metres, points on the current hand (its surface proxy, posed): each is
    jittered (Gaussian, ``spread_m``) and kept where :meth:`DepthImage.violation` is positive,
    so the points are free whatever the hand; a random ``count`` of them is returned. These are
    where a wrong hand lies, which samples spread over the whole view rarely reach.
    """
    copies = max(1, -(-2 * count // max(surface.shape[0], 1)))
    noise = torch.randn(copies, *surface.shape, generator=generator).to(surface)
    probes = (surface.detach()[None] + spread_m * noise).reshape(-1, 3)
    with torch.no_grad():
        free = probes[depth.violation(probes) > 0]
    if free.shape[0] > count:
        free = free[torch.randperm(free.shape[0], generator=generator)[:count].to(free.device)]
    return free
