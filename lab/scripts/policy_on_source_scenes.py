"""A policy's rollouts on the scenes its source demos were recorded in against new scenes of a
variant, with how far each new scene is from the nearest source demo's: whether a policy
trained on a few demos reproduces them and fails to generalise, or fails on both.

    python lab/scripts/policy_on_source_scenes.py --task stack_cube \\
        --policy data/policies/stack_cube_source/seed0/epoch00200.pt \\
        [--source data/source/stack_cube.zarr] [--variant D0] [--episodes 50] [--out FILE]

A scene's distance to a source demo: the horizontal distances [m] between each object's
initial position in the two scenes, summed over the task's objects. New scenes are the
evaluate stage's (evaluate.seed); every rollout runs on a freshly rebuilt scene. Prints,
for the source scenes and the new ones, the episodes that ended the first subtask and that
succeeded, and the new scenes by distance.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import json
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.learn.evaluation import evaluation_seed, rollout
from mimicgen_pipe.learn.training import load_rollout_policy

BINS = (0.0, 0.1, 0.2, np.inf)  # [m] of distance to the nearest source demo


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, help="a checkpoint of the train stage (.pt)")
    p.add_argument("--task", required=True)
    p.add_argument("--backend", default="maniskill")
    p.add_argument("--source", help="the source store (default: data/source/<task>.zarr)")
    p.add_argument("--variant", default="D0", help="the variant of the new scenes")
    p.add_argument("--episodes", type=int, default=50, help="new scenes")
    p.add_argument("--out", type=Path, help="a JSON file with every episode")
    args = p.parse_args()
    if args.out is not None and args.out.exists():  # before any work; nothing is replaced
        p.error(f"--out {args.out}: already exists; remove it or name another file")
    spec = backends.task_spec(args.backend, args.task)
    backends.check_variant(spec, args.variant)
    source = read_store(
        args.source or layout.source_store(args.task), task=args.task, kind="source"
    )
    policy = load_rollout_policy(args.policy)
    env = backends.make_env(args.backend, args.task)
    # (N, n_objects, 2): each source demo's objects' initial x, y (stored as x, y, z, wxyz)
    initial = np.asarray(source.episodes["initial_object_poses"])[:, :, :2]
    signals = [s.term_signal for s in spec.subtasks[:-1]]

    def run(seed: int, variant: str) -> dict:
        env.rebuild()
        env.reset(seed=seed, variant=variant)
        here = env.object_poses()
        xy = np.stack([here[o][:2, 3] for o in spec.objects])
        nearest = float(np.linalg.norm(initial - xy, axis=-1).sum(-1).min())
        env.rebuild()
        r = rollout(env, policy, seed, variant, spec.horizon, spec.objects, term_signals=signals)
        first = bool(r.subtask_ends) and r.subtask_ends[0] >= 0
        return {"seed": seed, "success": bool(r.success), "first_subtask": first,
                "nearest_source_m": round(nearest, 4)}  # fmt: skip

    seed0 = load_params().evaluate.seed
    rows = {
        "source_scenes": [run(int(s), "D0") for s in source.episodes["seed"]],
        "new_scenes": [
            run(evaluation_seed(seed0, args.variant, i), args.variant) for i in range(args.episodes)
        ],
    }
    env.close()
    first = spec.subtasks[0].name
    for name, episodes in rows.items():
        ended = sum(e["first_subtask"] for e in episodes)
        wins = sum(e["success"] for e in episodes)
        print(f"{name}: {len(episodes)} episodes, {ended} ended {first}, {wins} succeeded")
    new = rows["new_scenes"]
    median = np.median([e["nearest_source_m"] for e in new])
    print(f"new scenes' nearest source demo: median {median:.3f} m")
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        sel = [e for e in new if lo <= e["nearest_source_m"] < hi]
        print(f"  {lo:.1f}-{hi:.1f} m: {len(sel)} scenes, {sum(e['first_subtask'] for e in sel)} "
              f"ended {first}, {sum(e['success'] for e in sel)} succeeded")  # fmt: skip
    if args.out is not None:
        args.out.write_text(json.dumps({"policy": args.policy, **rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
