"""Two versions of the generator's recording, interleaved block by block in one process on
the same StackCube attempts: seconds per attempt and the generator's overhead of each.

    git worktree add /tmp/before <rev>   # a revision with the layered package (method/)
    .venv/bin/python lab/scripts/recorder_ab.py /tmp/before/mimicgen_pipe/method/generation.py \
        [--blocks 10] [--variant D0]

The other version's generation.py is loaded beside this tree's (the rest of the library is
this tree's), and the two take turns block by block, in alternating order, each block on a
rebuilt scene, so that this machine's drifting speed falls on both alike. Separate processes
run minutes apart on these machines differ by more than the recording does. Prints each
version's seconds per attempt, its overhead over stepping the same actions back to back,
and this tree's time over the other's.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import importlib.util
import sys
import time

import mimicgen_pipe.method.generation as this
from mimicgen_pipe import backends
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("other", help="the other version's mimicgen_pipe/method/generation.py")
    p.add_argument("--blocks", type=int, default=10)
    p.add_argument("--variant", default="D0")
    p.add_argument("--parsed", default="data/pose_noise/stack_cube.zarr")
    args = p.parse_args()
    spec_ = importlib.util.spec_from_file_location("other_generation", args.other)
    other = importlib.util.module_from_spec(spec_)
    sys.modules["other_generation"] = other  # dataclasses look their module up
    spec_.loader.exec_module(other)
    spec = backends.task_spec("maniskill", "stack_cube")
    sources = source_demos(read_store(args.parsed, ["target_pose"]), spec.objects)
    env = backends.make_env("maniskill", "stack_cube")
    versions = {"other": other, "this": this}
    seconds = dict.fromkeys(versions, 0.0)
    raw, steps = 0.0, 0
    for b in range(args.blocks):
        seeds = [attempt_seed(0, args.variant, b * ATTEMPTS_PER_BLOCK + i)
                 for i in range(ATTEMPTS_PER_BLOCK)]  # fmt: skip
        for name in sorted(versions, reverse=b % 2 == 1):
            mod = versions[name]
            env.rebuild()
            t0 = time.perf_counter()
            attempts = [
                mod.run_attempt(env, sources, spec, mod.GenerationConfig(), args.variant, s)
                for s in seeds
            ]
            seconds[name] += time.perf_counter() - t0
        env.rebuild()
        for a in attempts:
            env.reset(seed=a.seed, variant=args.variant)
            t0 = time.perf_counter()
            for action in a.steps["actions"]:
                env.step(action)
            raw += time.perf_counter() - t0
            steps += len(a.steps["actions"])
    n = args.blocks * ATTEMPTS_PER_BLOCK
    for name, s in seconds.items():
        print(f"{name:5s} {s / n:.4f} s/attempt, overhead {s / raw:.3f}, own work "
              f"{1e3 * (s - raw) / steps:.4f} ms/step")  # fmt: skip
    print(f"stepping alone {1e3 * raw / steps:.4f} ms/step; this / other "
          f"{seconds['this'] / seconds['other']:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
