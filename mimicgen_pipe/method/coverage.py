"""Support coverage of a dataset's initial scene configurations (paper Q).

Every object's initial (x, y, yaw) is binned into ``bins`` equal bins per dimension over the
reset bounds of the variant; the support coverage is the share of bins holding at least one
episode, per object (bins**3 bins) and jointly over all objects (bins**(3 * objects) bins,
the paper's n**6 for two objects).

Yaw is the top-down angle atan2(R[1, 0], R[0, 0]) of the object's x axis [rad], taken modulo
a full turn into [lo, lo + 2 pi) of the bounds. It is not folded by an object's symmetry:
a cube looks the same every 90 deg, but the generator carries the source grasp in
the cube's frame, so yaws 90 deg apart give grasps 90 deg apart (other arm configurations),
and the policy's observation carries the quaternion as it is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import ObjectBounds, TaskSpec

DIMENSIONS = ("x", "y", "yaw")
_OUTSIDE_TOL = 1e-6  # [m] or [rad]: resets sample up to their bounds, floats land on them


def reset_bounds(spec: TaskSpec, variant: str) -> list[ObjectBounds]:
    """The bounds of every object of ``spec`` in ``variant``, in spec.objects order. Raises
    InputError when the task spec lacks them."""
    if variant not in spec.reset_variants:
        raise InputError(
            f"task {spec.name}: no reset bounds for variant {variant!r} "
            f"(task spec has: {', '.join(spec.variants) or 'none'})"
        )
    per_object = spec.reset_variants[variant].bounds
    missing = [o for o in spec.objects if o not in per_object]
    if missing:
        raise InputError(
            f"task {spec.name}: reset bounds of variant {variant} lack object(s) "
            f"{', '.join(missing)}"
        )
    for o in spec.objects:
        for dim in DIMENSIONS:
            lo, hi = getattr(per_object[o], dim)
            # yaw may be fixed (lo == hi: one bin); a position range may not
            if not (
                math.isfinite(lo) and math.isfinite(hi) and (lo < hi or dim == "yaw" and lo == hi)
            ):
                raise InputError(
                    f"task {spec.name}: reset bounds of {o} in {variant}: {dim} range "
                    f"({lo}, {hi}) is empty"
                )
    return [per_object[o] for o in spec.objects]


def planar_pose(initial_poses: np.ndarray, bounds: Sequence[ObjectBounds]) -> np.ndarray:
    """(E, n_objects, 4, 4) world poses -> (E, n_objects, 3) [x, y, yaw], yaw wrapped into
    [lo, lo + 2 pi) of each object's bounds."""
    p = np.asarray(initial_poses, dtype=np.float64)
    yaw = np.arctan2(p[..., 1, 0], p[..., 0, 0])
    lo = np.array([b.yaw[0] for b in bounds])
    yaw = lo + np.mod(yaw - lo, 2 * np.pi)
    return np.stack([p[..., 0, 3], p[..., 1, 3], yaw], axis=-1)


def bin_index(
    values: np.ndarray, bounds: Sequence[ObjectBounds], bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """values (E, n_objects, 3) [x, y, yaw] -> (bin indices (E, n_objects, 3) in [0, bins),
    outside (E,) True where some value lies outside its bounds; those are put in the edge
    bin and counted apart)."""
    lo = np.array([[getattr(b, d)[0] for d in DIMENSIONS] for b in bounds])
    hi = np.array([[getattr(b, d)[1] for d in DIMENSIONS] for b in bounds])
    span = hi - lo
    # a fixed dimension (span 0, e.g. a yaw the reset does not vary) has one bin
    frac = np.where(span > 0, (values - lo) / np.where(span > 0, span, 1.0), 0.0)
    outside = ((values < lo - _OUTSIDE_TOL) | (values > hi + _OUTSIDE_TOL)).any(axis=(-1, -2))
    index = np.clip(np.floor(frac * bins).astype(np.int64), 0, bins - 1)
    return index, outside


@dataclass(frozen=True)
class Coverage:
    """Bin counts and support coverage of one set of episodes.

    counts: (n_objects, bins, bins, bins) episodes per object bin (x, y, yaw).
    object_coverage: (n_objects,) share [%] of non-empty object bins.
    joint_filled: non-empty joint bins; joint_total: bins**(3 * n_objects), a dimension the
    reset does not vary (fixed yaw) counting as one bin.
    episodes: episodes counted; outside: those with a value outside the bounds.
    """

    counts: np.ndarray
    object_coverage: np.ndarray
    joint_filled: int
    joint_total: int
    episodes: int
    outside: int

    @property
    def joint_coverage(self) -> float:
        """Share [%] of non-empty joint bins."""
        return 100.0 * self.joint_filled / self.joint_total


def support_coverage(
    initial_poses: np.ndarray, bounds: Sequence[ObjectBounds], bins: int
) -> Coverage:
    """Support coverage (paper Q) of episodes whose objects start at ``initial_poses``
    (E, n_objects, 4, 4) world frame, over ``bounds`` (one per object) with ``bins`` bins per
    dimension."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    poses = np.asarray(initial_poses, dtype=np.float64).reshape(-1, len(bounds), 4, 4)
    index, outside = bin_index(planar_pose(poses, bounds), bounds, bins)
    n_obj = len(bounds)
    counts = np.zeros((n_obj, bins, bins, bins), np.int64)
    for o in range(n_obj):
        np.add.at(counts[o], tuple(index[:, o].T), 1)
    joint = {tuple(row) for row in index.reshape(len(index), 3 * n_obj).tolist()}
    varied = [sum(getattr(b, d)[0] < getattr(b, d)[1] for d in DIMENSIONS) for b in bounds]
    object_bins = np.array([bins**k for k in varied])
    return Coverage(
        counts=counts,
        object_coverage=100.0 * (counts > 0).reshape(n_obj, -1).sum(axis=1) / object_bins,
        joint_filled=len(joint),
        joint_total=int(np.prod(object_bins)),
        episodes=len(index),
        outside=int(outside.sum()),
    )


def uniform_coverage(episodes: int, total_bins: int) -> float:
    """Expected coverage [%] of ``episodes`` scenes drawn uniformly over ``total_bins`` bins:
    the most a dataset of that size covers on average, bias or not (1 - (1 - 1/B)^E)."""
    return (
        100.0 * -math.expm1(episodes * math.log1p(-1.0 / total_bins))
        if total_bins > 1
        else (100.0 if episodes else 0.0)
    )


def coverage_metrics(
    objects: Sequence[str], generated: Coverage, attempted: Coverage, bins: int
) -> dict[str, float | int]:
    """Flat metrics: support coverage [%] of the generated (kept) episodes and of all attempted
    ones, per object and joint, with the counts behind them."""
    out: dict[str, float | int] = {
        "bins": bins,
        "joint_bins": generated.joint_total,
        "episodes": generated.episodes,
        "attempts": attempted.episodes,
        "outside_bounds": attempted.outside,
        "support_coverage_joint": generated.joint_coverage,
        "attempted_support_coverage_joint": attempted.joint_coverage,
        "uniform_support_coverage_joint": uniform_coverage(
            generated.episodes, generated.joint_total
        ),
    }
    for i, name in enumerate(objects):
        out[f"support_coverage_{name}"] = float(generated.object_coverage[i])
        out[f"attempted_support_coverage_{name}"] = float(attempted.object_coverage[i])
    return out


def bin_table(
    objects: Sequence[str],
    bounds: Sequence[ObjectBounds],
    generated: Coverage,
    attempted: Coverage,
) -> list[dict[str, object]]:
    """One row per object bin: its label, index and edges (x, y [m], yaw [deg]) and the
    generated and attempted episode counts, with the generation rate in the bin [%]."""
    bins = generated.counts.shape[1]
    rows = []
    for o, (name, b) in enumerate(zip(objects, bounds, strict=True)):
        edges = {d: np.linspace(*getattr(b, d), bins + 1) for d in DIMENSIONS}
        edges["yaw"] = np.degrees(edges["yaw"])
        for ix, iy, iw in np.ndindex(bins, bins, bins):
            gen, att = int(generated.counts[o, ix, iy, iw]), int(attempted.counts[o, ix, iy, iw])
            rows.append(
                {
                    "bin": f"{name} x{ix} y{iy} yaw{iw}",
                    "object": name,
                    "x_bin": ix,
                    "y_bin": iy,
                    "yaw_bin": iw,
                    "x_lo": round(float(edges["x"][ix]), 4),
                    "x_hi": round(float(edges["x"][ix + 1]), 4),
                    "y_lo": round(float(edges["y"][iy]), 4),
                    "y_hi": round(float(edges["y"][iy + 1]), 4),
                    "yaw_lo_deg": round(float(edges["yaw"][iw]), 2),
                    "yaw_hi_deg": round(float(edges["yaw"][iw + 1]), 2),
                    "generated": gen,
                    "attempted": att,
                    "dgr": round(100.0 * gen / att, 2) if att else "",
                }
            )
    return rows


def position_histogram(
    xy: np.ndarray, bounds: ObjectBounds, cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2-D histogram (cells x cells, indexed [x, y]) of positions ``xy`` (E, 2) [m] over the
    bounds, with its x and y edges."""
    xe = np.linspace(*bounds.x, cells + 1)
    ye = np.linspace(*bounds.y, cells + 1)
    h, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=(xe, ye))
    return h, xe, ye


def plot_heatmaps(
    path: str | Path,
    title: str,
    objects: Sequence[str],
    bounds: Sequence[ObjectBounds],
    generated_poses: np.ndarray,
    attempted_poses: np.ndarray,
    bins: int,
    cells: int = 15,
) -> Path:
    """Heat maps of initial object positions (PNG): per object, the attempted scenes, the
    generated (kept) ones and the share kept per cell, with the coverage bins' edges drawn
    over them. Poses are (E, n_objects, 4, 4) world frame; axes are world x, y [m]."""
    from mimicgen_pipe.core.figures import quiet_matplotlib_import

    with quiet_matplotlib_import():
        import matplotlib

        matplotlib.use("Agg")  # files only, no display
        import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(objects), 3, figsize=(12, 4.2 * len(objects)), squeeze=False, layout="constrained"
    )
    for o, (name, b) in enumerate(zip(objects, bounds, strict=True)):
        att, xe, ye = position_histogram(attempted_poses[:, o, :2, 3], b, cells)
        gen, _, _ = position_histogram(generated_poses[:, o, :2, 3], b, cells)
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.where(att > 0, 100.0 * gen / att, np.nan)
        panels = (
            (att, f"{name}: attempted ({len(attempted_poses)})", "viridis", "episodes"),
            (gen, f"{name}: generated ({len(generated_poses)})", "viridis", "episodes"),
            (rate, f"{name}: kept per cell [%]", "RdYlGn", "%"),
        )
        for ax, (h, label, cmap, unit) in zip(axes[o], panels, strict=True):
            vmax = 100.0 if unit == "%" else max(1.0, float(np.nanmax(att)))
            mesh = ax.pcolormesh(xe, ye, h.T, cmap=cmap, vmin=0.0, vmax=vmax)
            for edge in np.linspace(*b.x, bins + 1):
                ax.axvline(edge, color="white", lw=1.5)
            for edge in np.linspace(*b.y, bins + 1):
                ax.axhline(edge, color="white", lw=1.5)
            ax.set_title(label)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.set_aspect("equal")
            fig.colorbar(mesh, ax=ax, label=unit, shrink=0.8)
    fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    # no timestamp or version in the file: the same data gives the same bytes
    fig.savefig(tmp, dpi=80, format="png", metadata={"Software": None})
    plt.close(fig)
    return tmp.replace(path)


def write_table(path: str | Path, rows: Sequence[Mapping[str, object]]) -> Path:
    """Rows as CSV (the header from the first row)."""
    import csv

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return tmp.replace(path)


@dataclass(frozen=True)
class CoverageJob:
    """One coverage run, checked (mimicgen_pipe.stages.coverage.resolve): the initial scenes
    of ``variant`` of ``task`` that generate run ``run_id`` (on ``backend`` with ``robot``)
    kept, ``kept``, and attempted, kept or failed, ``attempted``: (E, n_objects, 4, 4)
    initial poses of ``objects``, world frame [m], binned in ``bins`` bins per dimension
    over the variant's reset ``bounds``. Read from the kept store ``kept_path`` and the
    failed store ``failed_path``; written as the metrics JSON ``metrics_path``, the per-bin
    counts ``table`` (CSV) and the heat maps ``heatmap`` (PNG)."""

    task: str
    variant: str
    backend: str
    robot: str | None
    run_id: str | None
    objects: tuple[str, ...]
    bounds: tuple[ObjectBounds, ...]
    bins: int
    kept: np.ndarray
    attempted: np.ndarray
    kept_path: Path
    failed_path: Path
    metrics_path: Path
    table: Path
    heatmap: Path


def measure_coverage(job: CoverageJob) -> tuple[Coverage, Coverage]:
    """The support coverage of the job's generated (kept) and attempted initial scenes;
    writes the per-bin counts and the heat maps."""
    generated = support_coverage(job.kept, job.bounds, job.bins)
    attempted = support_coverage(job.attempted, job.bounds, job.bins)
    write_table(job.table, bin_table(job.objects, job.bounds, generated, attempted))
    plot_heatmaps(
        job.heatmap,
        f"{job.task} {job.variant}: initial object positions ({job.bins} coverage bins per "
        f"dimension, edges in white)\njoint support coverage {generated.joint_coverage:.1f}% "
        f"generated, {attempted.joint_coverage:.1f}% attempted",
        job.objects,
        job.bounds,
        job.kept,
        job.attempted,
        job.bins,
    )
    return generated, attempted
