"""Mesh benchmark: ``lisa mesh`` (coarse-to-fine marching cubes of a LISA hand) against dense
evaluation of the same grid.

``python -m benchmarks mesh [--model PATH] [--resolutions 128,256] [--json FILE]``

The hand: the shipped model (``lisa_hand/assets/lisa_pretrained.pt``) when it exists, or the
model given with ``--model``, else a fresh ``LisaModel()`` (default
:class:`~lisa_hand.fields.FieldConfig`, the paper's sizes) at its geometric initialisation, a
blob of a hand on the average skeleton (``AVERAGE_REST_JOINTS``); posed with
:func:`benchmarks.field.bench_pose` and the model's mean codes. The output says which.

Timed in one run, at each resolution (grid samples along the side of the cube around the hand):

* **fast**: :func:`lisa_hand.inference.mesh_hand` as ``lisa mesh`` runs it: the surface box, the
  grid evaluated coarse to fine (full resolution only near the zero level set), marching cubes,
  then colours and skinning weights at the vertices;
* **reference**: the same with every grid point evaluated (``coarse_to_fine=False``).

Accuracy: the mean vertex-to-surface distance between the two meshes, both ways (mm); the
coarse-to-fine grid equals the dense one wherever the Lipschitz bound holds, so it is ~0.
Targets (on 2 CPU cores): 2 s at 128^3, 8 s at 256^3.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import torch

from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["TARGET_SECONDS", "bench_hand", "run_mesh_benchmark", "main"]

TARGET_SECONDS = {128: 2.0, 256: 8.0}
"""The targets on 2 CPU cores, seconds per resolution."""


def bench_hand(model_path: str | None = None, seed: int = 0):
    """The benchmark's hand: (TrainedModel, HandParams, description).

    model_path: a trained model (file or run); None: the shipped model when it exists, else a
    geometric-init ``LisaModel()``.
    """
    from lisa_hand.fields import FieldConfig
    from lisa_hand.model.lisa import LisaModel
    from lisa_hand.model.trained import DEFAULT_BETA, TrainedModel, default_model_path, load_trained
    from lisa_hand.skeleton import AVERAGE_REST_JOINTS
    from lisa_hand.skeleton.params import HandParams

    from .field import bench_pose

    torch.manual_seed(seed)  # the untrained model's random layers
    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(AVERAGE_REST_JOINTS)
    pose = bench_pose(generator)[0]
    if model_path is None and default_model_path().is_file():
        model_path = str(default_model_path())
    if model_path is not None:
        model = load_trained(model_path)
        description = f"trained model {model.source}"
    else:
        config = FieldConfig()
        field = LisaModel(config, init_rest_joints=rest_joints).eval()
        model = TrainedModel(
            field=field,
            shape_codes=torch.zeros(1, config.shape_dim),
            color_codes=0.5 * torch.randn(1, config.color_dim, generator=generator),
            subject_ids=["bench"],
            beta=DEFAULT_BETA,
            gain=torch.ones(3),
            bias=torch.zeros(3),
            source="geometric init",
        )
        description = (
            "untrained LisaModel() (default FieldConfig, geometric init: a blob of a hand; "
            "no shipped model found)"
        )
    params = HandParams(
        pose=pose,
        translation=torch.zeros(3),
        rest_joints=rest_joints,
        shape_code=model.mean_shape_code(),
        color_code=model.mean_color_code(),
    )
    return model, params, description


def _mean_distance(fast, reference) -> dict:
    from lisa_hand.metrics import mesh_distances

    distances = mesh_distances(
        fast.vertices, fast.faces, reference.vertices, reference.faces
    ).to_dict()
    same_topology = fast.num_vertices == reference.num_vertices and bool(
        (fast.faces == reference.faces).all() if fast.num_faces == reference.num_faces else False
    )
    max_vertex_mm = (
        float(abs(fast.vertices - reference.vertices).max()) * 1e3 if same_topology else None
    )
    return {
        "mean_distance_mm": 0.5
        * (distances["v2s_recon_to_scan_mm"] + distances["v2s_scan_to_recon_mm"]),
        "v2s_fast_to_reference_mm": distances["v2s_recon_to_scan_mm"],
        "v2s_reference_to_fast_mm": distances["v2s_scan_to_recon_mm"],
        "same_faces": same_topology,
        "max_vertex_difference_mm": max_vertex_mm,
    }


def _mesh_run(model, params, resolution: int, config, log: Callable[[str], None]) -> dict:
    """Mesh at one resolution coarse to fine and densely; -> the run's numbers (logged)."""
    from dataclasses import replace

    from lisa_hand.inference import mesh_hand_with_stats

    fast = mesh_hand_with_stats(model, params, resolution, config)
    reference = mesh_hand_with_stats(
        model, params, resolution, replace(config, coarse_to_fine=False)
    )
    accuracy = _mean_distance(fast.mesh, reference.mesh)
    target = TARGET_SECONDS.get(resolution)
    run = {
        "resolution": resolution,
        "seconds": fast.seconds_total,
        "reference_seconds": reference.seconds_total,
        "speedup": reference.seconds_total / fast.seconds_total,
        "target_seconds": target,
        **accuracy,
        "voxel_size_mm": fast.voxel_size * 1e3,
        "grid_grown": fast.grown,
        "vertices": fast.mesh.num_vertices,
        "faces": fast.mesh.num_faces,
        "evaluations": fast.extraction.num_evaluations,
        "reference_evaluations": reference.extraction.num_evaluations,
        "grid_points": fast.extraction.num_grid_points,
        "stages": {
            "evaluation": fast.extraction.seconds_evaluation,
            "marching_cubes": fast.extraction.seconds_marching_cubes,
            "attributes": fast.seconds_attributes,
        },
        "reference_stages": {
            "evaluation": reference.extraction.seconds_evaluation,
            "marching_cubes": reference.extraction.seconds_marching_cubes,
            "attributes": reference.seconds_attributes,
        },
    }
    versus = f", target {target:.0f} s" if target is not None else ""
    log(
        f"{resolution}^3: coarse to fine {fast.seconds_total:.2f} s "
        f"({fast.extraction.num_evaluations / 1e6:.2f} M evaluations: field "
        f"{fast.extraction.seconds_evaluation:.2f} s, "
        f"marching cubes {fast.extraction.seconds_marching_cubes:.2f} s, colours+weights "
        f"{fast.seconds_attributes:.2f} s){versus}; dense {reference.seconds_total:.2f} s "
        f"({reference.extraction.num_evaluations / 1e6:.2f} M), x"
        f"{run['speedup']:.1f}; mean distance {accuracy['mean_distance_mm']:.2e} mm "
        f"(same faces: {accuracy['same_faces']}); {fast.mesh.num_vertices} vertices, voxel "
        f"{run['voxel_size_mm']:.2f} mm"
    )
    return run


def run_mesh_benchmark(
    resolutions: tuple[int, ...] = (128, 256),
    model_path: str | None = None,
    *,
    lipschitz: float | None = None,
    seed: int = 0,
    log: Callable[[str], None] = print,
) -> dict:
    """Mesh the benchmark hand coarse to fine and densely at each resolution; return numbers."""
    from lisa_hand.inference import MeshConfig, hand_field

    model, params, description = bench_hand(model_path, seed)
    config = MeshConfig() if lipschitz is None else MeshConfig(lipschitz=lipschitz)
    log(
        f"mesh benchmark: {description}; torch threads {torch.get_num_threads()}, Lipschitz "
        f"bound {config.lipschitz}, load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores"
    )
    results: dict = {
        "benchmark": "mesh",
        "model": description,
        "threads": torch.get_num_threads(),
        "lipschitz": config.lipschitz,
        "load_average_at_start": os.getloadavg()[0],
        "runs": [],
    }
    # Warm-up (first calls allocate and pick kernels), not timed.
    hand = hand_field(model, params)
    with torch.no_grad():
        hand.sdf_fn()(torch.zeros(4096, 3))
    for resolution in resolutions:
        results["runs"].append(_mesh_run(model, params, resolution, config, log))
    for key in ("resolution", "seconds", "reference_seconds", "mean_distance_mm"):
        results[key] = [run[key] for run in results["runs"]]
    results["load_average_at_end"] = os.getloadavg()[0]
    log(
        f"load average (1 min) at start {results['load_average_at_start']:.1f}, at end "
        f"{results['load_average_at_end']:.1f}"
    )
    return results


def _parse_resolutions(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--resolutions must look like 128,256, got {text!r}") from None
    if not values or min(values) < 8:
        raise ValueError(f"--resolutions must be integers >= 8, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks mesh [options]``; returns the results."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks mesh", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--model", default=None, help="trained model (default: the shipped one, else an "
        "untrained geometric-init LisaModel)",
    )  # fmt: skip
    parser.add_argument("--resolutions", default="128,256", help="grid sizes, comma separated")
    parser.add_argument("--lipschitz", type=float, default=None, help="override the bound")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (default: unchanged)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    resolutions = _parse_resolutions(args.resolutions)
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    start = time.perf_counter()
    with cpu_threads(args.threads):
        results = run_mesh_benchmark(
            resolutions, args.model, lipschitz=args.lipschitz, seed=args.seed
        )
    results["benchmark_seconds"] = time.perf_counter() - start
    write_results(args.json, results)
    return results


if __name__ == "__main__":
    main()
