"""Free space of a one-view scan: points a depth sensor saw to be empty.

A sensor at ``viewpoint`` that returned the point ``x`` saw through the segment from itself to
``x``, and where it returned nothing (pixels around the hand with no point) it saw through the
whole ray. So a hand fitted to a one-view scan must not put surface there: a finger left straight
in front of the sensor where the real one curls away out of sight fits every scan point, yet the
sensor would have seen it. :func:`free_space_points` samples such empty points near the scan;
the surface stage asks the field to be outside at them (``FitPointsConfig.free_space_weight``,
:mod:`.surface_stage`). A full (many-view) scan has no single viewpoint and gets none.

Both kinds are drawn near the hand, where a wrong hand can be:

* *in front*: on the ray of a scan point, between ``margin_m`` and ``depth_m`` before it;
* *beside*: on rays through empty pixels of the scan's depth image (gnomonic projection about
  the mean viewing direction, ``pixel_m`` pixels at the mean range, the occupied ones dilated by
  ``dilate_px`` so that gaps between sparse points stay unknown), within ``border_m`` of the
  scan's image and between ``depth_m`` before its nearest and beyond its farthest range.
"""

from __future__ import annotations

import torch

__all__ = ["DepthImage", "free_space_points", "free_points_near"]


def free_space_points(
    points: torch.Tensor,
    viewpoint: torch.Tensor,
    count: int,
    generator: torch.Generator,
    *,
    margin_m: float = 0.003,
    depth_m: float = 0.02,
    pixel_m: float = 0.002,
    dilate_px: int = 2,
    border_m: float = 0.03,
    beside_fraction: float = 0.5,
) -> torch.Tensor:
    """[count, 3] world metres: empty points of the one-view scan ``points`` (module docstring).

    points: [N, 3] world metres, what the sensor returned. viewpoint: [3] world metres, the
    sensor's position. generator: a CPU generator (the samples are deterministic given it).
    beside_fraction: the share of the points drawn beside the scan (the rest in front of it);
    when no pixel around the scan is empty, all are in front.
    """
    like = dict(device=points.device, dtype=points.dtype)
    viewpoint = viewpoint.to(**like)
    rays = points - viewpoint
    ranges = rays.norm(dim=-1)
    if not bool((ranges > margin_m).all()):
        raise ValueError("viewpoint: the sensor position lies within the scan's points")
    units = rays / ranges[:, None]
    axis = units.mean(0)
    axis = axis / axis.norm()
    helper = torch.eye(3, **like)[int(torch.argmin(axis.abs()))]
    e1 = torch.linalg.cross(axis, helper)
    e1 = e1 / e1.norm()
    e2 = torch.linalg.cross(axis, e1)
    along = units @ axis
    if not bool((along > 0.2).all()):
        raise ValueError("viewpoint: the scan spans too wide an angle from the sensor position "
                         "to be one view of it")
    plane = torch.stack([units @ e1, units @ e2], dim=-1) / along[:, None]  # [N, 2] gnomonic
    pixel = pixel_m / float(ranges.mean())
    border = border_m / float(ranges.mean())
    low = plane.amin(0) - border
    size = ((plane.amax(0) + border - low) / pixel).ceil().long() + 1
    cells = ((plane - low) / pixel).long()
    occupied = torch.zeros(int(size[0]), int(size[1]), dtype=torch.bool, device=points.device)
    occupied[cells[:, 0], cells[:, 1]] = True
    if dilate_px > 0:
        occupied = torch.nn.functional.max_pool2d(
            occupied[None, None].float(), 2 * dilate_px + 1, stride=1, padding=dilate_px
        )[0, 0] > 0
    empty = (~occupied).nonzero()

    def uniform(num: int) -> torch.Tensor:
        return torch.rand(num, generator=generator).to(**like)

    beside = int(round(count * beside_fraction)) if empty.shape[0] > 0 else 0
    front = count - beside
    chosen = torch.randint(points.shape[0], (front,), generator=generator).to(points.device)
    back = margin_m + (depth_m - margin_m) * uniform(front)
    samples = [viewpoint + units[chosen] * (ranges[chosen] - back)[:, None]]
    if beside > 0:
        picked = empty[torch.randint(empty.shape[0], (beside,), generator=generator)
                       .to(points.device)]
        coords = low + (picked.to(**like) + torch.stack([uniform(beside), uniform(beside)], -1)) \
            * pixel
        directions = axis + coords[:, :1] * e1 + coords[:, 1:] * e2
        directions = directions / directions.norm(dim=-1, keepdim=True)
        near = float(ranges.min()) - depth_m
        far = float(ranges.max()) + depth_m
        distance = near + (far - near) * uniform(beside)
        samples.append(viewpoint + directions * distance[:, None])
    return torch.cat(samples)


class DepthImage:
    """The scan's depth image seen from its sensor, to tell how far points lie in its free space.

    Pixels as in :func:`free_space_points` (gnomonic about the mean viewing direction,
    ``pixel_m`` at the mean range, occupied pixels dilated by ``dilate_px``, ``border_m`` around).
    :meth:`violation` is 0 for a point behind the scan's nearest return at its pixel (or less
    than ``margin_m`` before it), the depth by which it lies before that return otherwise, and
    for a point on an empty pixel its distance across the image to the nearest occupied pixel
    (at its range), plus ``margin_m``.
    """

    def __init__(self, points: torch.Tensor, viewpoint: torch.Tensor, *,
                 margin_m: float = 0.003, pixel_m: float = 0.002, dilate_px: int = 2,
                 border_m: float = 0.03) -> None:
        """points: [N, 3] world metres (what the sensor returned); viewpoint: [3] world
        metres."""
        from scipy.ndimage import distance_transform_edt

        like = dict(device=points.device, dtype=points.dtype)
        self.viewpoint = viewpoint.to(**like)
        self.axis, self.e1, self.e2 = _view_frame(points - self.viewpoint)
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


def _view_frame(rays: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(the mean viewing direction, two unit vectors across it) of rays [N, 3]."""
    like = dict(device=rays.device, dtype=rays.dtype)
    axis = (rays / rays.norm(dim=-1, keepdim=True)).mean(0)
    axis = axis / axis.norm()
    helper = torch.eye(3, **like)[int(torch.argmin(axis.abs()))]
    e1 = torch.linalg.cross(axis, helper)
    e1 = e1 / e1.norm()
    return axis, e1, torch.linalg.cross(axis, e1)


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
