"""How well a learned detector's box places a container in 3-D: from the depth in the box
(``box_center_3d``, the network alone) against standing it on the table the geometric
detector found (``box_on_table``, what the hybrid detector does; from the depth where the
box is at the image border or the container's foot is hidden).

The boxes are those of the true containers' models (the bottle model for bottles, a
cylinder for cups) in rendered cluttered scenes, exact or with every edge moved by Gaussian
pixel noise (a network's boxes are not exact), so the table says what each placement does
with a given box, not how good a network is. Clear cups return depth on a tenth to a fifth
of their front: from the depth in their box they land on what lies behind them.

    python benchmarks/bench_box_placement.py [--scenes 40] [--seed 0] [--noise 0 2 4] [--visible]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from armvision.camera.frames import project
from armvision.config import load_config
from armvision.eval.objects import (
    _Counts,
    _render,
    _score_scene,
    _true_objects,
    surface_samples_obj,
)
from armvision.geometry import inv_T, transform_points
from armvision.perception.detection import FrameContext, cylinder_box, detections_from_boxes
from armvision.perception.geometric import GeometricDetector, bottle_box
from armvision.perception.hybrid import HybridDetector


class _Oracle:
    """A network that boxes what it is given (``boxes``: (box, label) pairs)."""

    def __init__(self) -> None:
        self.boxes: list[tuple[tuple[float, ...], str]] = []

    def detect(self, frame, context=None):
        return detections_from_boxes(
            frame,
            np.array([box for box, _ in self.boxes]).reshape(-1, 4),
            np.ones(len(self.boxes)),
            [label for _, label in self.boxes],
            0.3,
            25.0,
            None if context is None else context.table_plane,
        )


def _visible_box(intr, truth, name: str, true_depth) -> tuple[float, ...] | None:
    """The pixel box of the object's surface samples that face the camera and are not
    hidden in the exact depth render (5 mm): what of it a network could box."""
    state = next(s for s in truth.objects if s.spec.name == name)
    spec = state.spec
    T_cam_obj = inv_T(truth.T_base_cam) @ state.T_base_obj
    points, normals = surface_samples_obj(spec.label, spec.radius, spec.height, spec.body_height)
    p_cam = transform_points(T_cam_obj, points)
    facing = np.einsum("ij,ij->i", normals @ T_cam_obj[:3, :3].T, -p_cam) > 0.0
    uv = project(intr, p_cam[facing])
    px = np.rint(uv).astype(int)
    inside = (px[:, 0] >= 0) & (px[:, 0] < intr.width) & (px[:, 1] >= 0) & (px[:, 1] < intr.height)
    seen = np.zeros(len(uv), dtype=bool)
    seen[inside] = true_depth[px[inside, 1], px[inside, 0]] >= p_cam[facing][inside, 2] - 0.005
    if seen.sum() < 10:
        return None
    lo, hi = uv[seen].min(axis=0), uv[seen].max(axis=0)
    return (float(lo[0]), float(lo[1]), float(hi[0]) + 1.0, float(hi[1]) + 1.0)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise", type=float, nargs="+", default=[0.0, 2.0, 4.0])
    parser.add_argument(
        "--visible",
        action="store_true",
        help="box only the visible part of each container (as a network would)",
    )
    args = parser.parse_args(argv)
    config = load_config(None, ["sim.profile=cluttered"])
    config = dataclasses.replace(config, sim=dataclasses.replace(config.sim, randomize_camera=True))
    rng = np.random.default_rng(args.seed)
    # (class, noise, placement) -> centre errors in mm, NaN where nothing was placed
    errors: dict[tuple[str, float, str], list[float]] = {}
    # (class, noise) -> [visible, found with the label, centre errors mm]: the hybrid detector
    # end to end, its network an oracle that boxes every visible container
    hybrid: dict[tuple[str, float], list] = {}
    for seed in range(args.seed, args.seed + args.scenes):
        frame, true_depth, truth, q = _render(config, seed, "sleep")
        context = FrameContext(T_base_cam=truth.T_base_cam, joint_positions=q)
        geometric = GeometricDetector(seed=seed)
        geometric.detect(frame, context)
        normal, offset = geometric.last_plane
        intr = frame.intrinsics
        objects = _true_objects(frame, true_depth, truth, 0.3)
        oracle = {sigma: _Oracle() for sigma in args.noise}
        for obj in objects:
            if obj["truth"] not in ("bottle", "cup") or not obj["visible"]:
                continue
            center = np.asarray(obj["center_cam"])
            foot = center - 0.5 * obj["height"] * normal
            if obj["truth"] == "bottle":
                box = bottle_box(intr, foot, normal, obj["radius"], obj["height"])
            else:
                box = cylinder_box(intr, center, normal, obj["radius"], obj["height"])
            if args.visible:
                seen = _visible_box(intr, truth, obj["name"], true_depth)
                if seen is None:
                    continue
                # The silhouette's bottom and sides where they are seen; where the visible
                # samples stop short of one by more than 2 px, a nearer object hides it
                # (the top, seen from above, is the far rim, which has no outer samples).
                box = (
                    box[0] if seen[0] <= box[0] + 2.0 else seen[0],
                    box[1],
                    box[2] if seen[2] >= box[2] - 2.0 else seen[2],
                    box[3] if seen[3] >= box[3] - 2.0 else seen[3],
                )
            kind = "clear cups" if obj["kind"] in ("clear_cup", "tumbler") else obj["truth"] + "s"
            for sigma in args.noise:
                noisy = tuple(float(v) for v in np.asarray(box) + rng.normal(0.0, sigma, 4))
                oracle[sigma].boxes.append((noisy, obj["truth"]))
                for name, plane in (
                    ("depth in the box", None),
                    ("on the table, else depth", (normal, offset)),
                ):
                    placed = detections_from_boxes(
                        frame, np.array([noisy]), np.ones(1), [obj["truth"]], 0.3, 25.0, plane
                    )
                    error = (
                        np.nan
                        if not placed
                        else 1e3 * np.linalg.norm(placed[0].center_cam - center)
                    )
                    errors.setdefault((kind, sigma, name), []).append(float(error))
        for sigma in args.noise:
            found = HybridDetector(oracle[sigma], GeometricDetector(seed=seed)).detect(
                frame, context
            )
            scored = [dict(obj) for obj in objects]
            _score_scene(scored, found, 0.05, _Counts())  # type: ignore[arg-type]
            for obj in scored:
                if obj["truth"] not in ("bottle", "cup") or not obj["visible"]:
                    continue
                kind = (
                    "clear cups" if obj["kind"] in ("clear_cup", "tumbler") else obj["truth"] + "s"
                )
                tally = hybrid.setdefault((kind, sigma), [0, 0, []])
                tally[0] += 1
                if obj["label"] == obj["truth"]:
                    tally[1] += 1
                    tally[2].append(obj["center_error_mm"])
    print(
        f"\nA container's centre from its box, {args.scenes} cluttered scenes from seed "
        f"{args.seed} (box edges with Gaussian noise of the given sigma)\n"
    )
    print(
        "| containers | box noise px | placement | boxes | placed | within 5 cm | median mm |",
        end="",
    )
    print(" p90 mm |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    summary = {}
    for (kind, sigma, name), values in sorted(errors.items()):
        e = np.array(values)
        ok = e[np.isfinite(e)]
        within = float(np.mean(e < 50.0))
        median = float(np.median(ok)) if len(ok) else float("nan")
        p90 = float(np.percentile(ok, 90)) if len(ok) else float("nan")
        print(
            f"| {kind} | {sigma:g} | {name} | {len(e)} | {len(ok)} | {within:.3f} | "
            f"{median:.1f} | {p90:.1f} |"
        )
        summary[f"{kind}, {sigma:g} px, {name}"] = {"within_5cm": within, "median_mm": median}
    print(
        "\nThe hybrid detector end to end, its network an oracle boxing every visible "
        "container as above (found: with its label, within 5 cm)\n"
    )
    print("| containers | box noise px | visible | found | centre median mm | p90 mm |")
    print("|---|---:|---:|---:|---:|---:|")
    for (kind, sigma), (visible, hits, errs) in sorted(hybrid.items()):
        median = float(np.median(errs)) if errs else float("nan")
        p90 = float(np.percentile(errs, 90)) if errs else float("nan")
        print(f"| {kind} | {sigma:g} | {visible} | {hits} | {median:.1f} | {p90:.1f} |")
        summary[f"hybrid, {kind}, {sigma:g} px"] = {"found": hits / visible, "median_mm": median}
    return summary


if __name__ == "__main__":
    main()
