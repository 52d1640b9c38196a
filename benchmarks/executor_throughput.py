"""Throughput as workers grow: the same StackCube attempts on the local pool and on Ray at 1,
2, 4, ... workers (up to this machine's CPUs), and on a Ray of two raylets on this machine (a
head and a second node joined to it, one CPU each, token authentication on, as a cluster
runs); demos per hour and the efficiency per worker, one after the other in one run;
written to metrics/benchmarks/executor_throughput.json.

    python benchmarks/executor_throughput.py [--parsed data/pose_noise/stack_cube.zarr]
        [--variant D0] [--attempts 160] [--max-workers N]

Each run is the stage's real path: blocks on rebuilt scenes, every finished block saved to a
work directory, results taken in block order. Worker start-up (spawning, building the
simulator) is inside each timing, as a stage pays it; starting Ray is not (a cluster is
normally up already) and is printed apart. Every run must make the same attempts as the
local 1-worker run, bit for bit (every step array of every attempt), which is checked and
recorded.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _machine import figures_path, machine

from mimicgen_pipe import backends
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import Attempt, GenerationConfig
from mimicgen_pipe.run.executors import Executor
from mimicgen_pipe.run.resume import WorkDir
from mimicgen_pipe.run.runner import (
    AttemptBlockCodec,
    AttemptJob,
    attempt_seed,
    run_attempts,
    source_demos,
)

OUT = figures_path(__file__)


def digest(a: Attempt) -> str:
    """An attempt's seed, outcome and every step array (names, dtypes, shapes, bytes)."""
    h = hashlib.sha256(f"{a.seed} {a.success}".encode())
    for k, v in a.steps.items():
        h.update(f"{k} {v.dtype} {v.shape}".encode())
        h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


def timed(job: AttemptJob, seeds: list[int], executor: Executor, tmp: Path) -> tuple[float, list]:
    """Seconds for the whole run on ``executor`` and its attempts in order."""
    work = WorkDir.open(tmp / f"{executor.kind}{executor.workers}.zarr", "benchmark",
                        AttemptBlockCodec(seeds))  # fmt: skip
    t0 = time.perf_counter()
    results = [a for _, a, _ in run_attempts(job, seeds, executor, work)]
    seconds = time.perf_counter() - t0
    work.remove()
    return seconds, results


def worker_counts(most: int) -> list[int]:
    """1, 2, 4, ... up to ``most``, and ``most`` itself."""
    counts, n = [], 1
    while n < most:
        counts.append(n)
        n *= 2
    return counts + [most]


def two_raylets(job: AttemptJob, seeds: list[int], tmp: Path) -> tuple[float, list, float]:
    """The attempts on a Ray of two raylets here (a head and a node joined to it, one CPU
    each) with token authentication on, reached by address as a cluster is; seconds, the
    attempts, and the seconds the two nodes took to start. Run in a process of its own: Ray
    keeps what it read of token authentication for the life of a process."""
    import ray
    from ray._raylet import Config
    from ray.cluster_utils import Cluster

    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(16)
    os.environ.pop("RAY_ADDRESS", None)
    Config.initialize("")  # Ray reads RAY_AUTH_MODE once per process: again now
    t0 = time.perf_counter()
    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "object_store_memory": 100 * 2**20,
                        "include_dashboard": False},
    )  # fmt: skip
    try:
        cluster.add_node(num_cpus=1, object_store_memory=100 * 2**20)
        cluster.wait_for_nodes()
        started = time.perf_counter() - t0
        seconds, attempts = timed(job, seeds, Executor("ray", 2, cluster.address), tmp)
        ray.shutdown()
    finally:
        cluster.shutdown()
    return seconds, attempts, started


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parsed", default="data/pose_noise/stack_cube.zarr")
    p.add_argument("--variant", default="D0")
    p.add_argument("--attempts", type=int, default=160)
    p.add_argument("--max-workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--two-raylets-to", type=Path, help=argparse.SUPPRESS)  # the child's run
    args = p.parse_args()
    spec = backends.task_spec("maniskill", "stack_cube")
    job = AttemptJob(
        make_env=functools.partial(backends.make_env, "maniskill", "stack_cube", "panda"),
        sources=source_demos(read_store(args.parsed, kind="parsed"), spec.objects),
        spec=spec,
        config=GenerationConfig(),
        variant=args.variant,
    )
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    if args.two_raylets_to:
        with tempfile.TemporaryDirectory() as tmp:
            seconds, attempts, started = two_raylets(job, seeds, Path(tmp))
        out = {"seconds": seconds, "started": started, "digests": [digest(a) for a in attempts],
               "kept": sum(a.success for a in attempts)}  # fmt: skip
        args.two_raylets_to.write_text(json.dumps(out))
        return
    import ray

    from mimicgen_pipe.run.executors.ray import _connect

    runs: list[dict] = []
    reference: list[str] = []

    def record(kind: str, workers: int, seconds: float, digests: list[str], kept: int,
               **extra) -> None:  # fmt: skip
        reference[:] = reference or digests
        runs.append({
            "executor": kind, "workers": workers, "seconds": round(seconds, 2),
            "attempts_per_second": round(len(digests) / seconds, 3),
            "demos": kept,
            "demos_per_hour": round(3600 * kept / seconds),
            "same_attempts_as_local_1": digests == reference,
            **extra,
        })  # fmt: skip
        r = runs[-1]
        print(f"{kind:14s} {workers} worker(s) {seconds:7.1f} s  {r['attempts_per_second']:5.2f} "
              f"attempts/s  {r['demos_per_hour']:6d} demos/h  same attempts: "
              f"{r['same_attempts_as_local_1']}", flush=True)  # fmt: skip

    def run(executor: Executor, tmp: str) -> tuple[float, list[str], int]:
        seconds, attempts = timed(job, seeds, executor, Path(tmp))
        return seconds, [digest(a) for a in attempts], sum(a.success for a in attempts)

    with tempfile.TemporaryDirectory() as tmp:
        for n in worker_counts(args.max_workers):
            record("local", n, *run(Executor("local", n), tmp))
            t0 = time.perf_counter()
            _connect(n, None)  # the local Ray the executor would start, started ahead
            ray_start = time.perf_counter() - t0
            record("ray", n, *run(Executor("ray", n), tmp), ray_start_seconds=round(ray_start, 1))
            ray.shutdown()
        child = Path(tmp) / "two_raylets.json"
        subprocess.run([sys.executable, __file__, "--parsed", args.parsed, "--variant",
                        args.variant, "--attempts", str(args.attempts), "--two-raylets-to",
                        str(child)], check=True)  # fmt: skip
        two = json.loads(child.read_text())
        record("ray, 2 raylets", 2, two["seconds"], two["digests"], two["kept"],
               ray_start_seconds=round(two["started"], 1))  # fmt: skip
    base = {r["executor"]: r["attempts_per_second"] for r in runs if r["workers"] == 1}
    for r in runs:
        one = base.get(r["executor"].split(",")[0], base["local"])
        r["efficiency_per_worker"] = round(r["attempts_per_second"] / (r["workers"] * one), 3)
    dgr = 100 * runs[0]["demos"] / len(seeds)
    print(f"\nStackCube {args.variant}: {args.attempts} attempts, DGR {dgr:.1f} %")
    print("efficiency per worker (throughput / (workers x the same executor's 1-worker)):")
    for r in runs:
        print(f"  {r['executor']:14s} {r['workers']}: {r['efficiency_per_worker']:.3f}")
    figures = {
        "task": "stack_cube",
        "variant": args.variant,
        "attempts": args.attempts,
        "dgr": round(float(dgr), 2),
        **machine(),
        "runs": runs,
    }
    OUT.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
