"""Where a stack_pyramid policy's rollouts fail: how cube A leaves the hand and where it
lands beside cube B, whether the hand goes on to cube C, and how the scene ends.

    python lab/scripts/stack_pyramid_rollouts.py \\
        --policy data/policies/stack_pyramid_D0_paper_h100/seed0/epoch00300.pt [more .pt] \\
        [--episodes 50] [--variant D0] [--component most_likely] [--out rollouts.json]

Rolls each checkpoint out on the evaluate stage's first scenes of the variant as the stage
does (its seeds, blocks and torch threads, in one process: the same rollouts), up to the
task's horizon, and prints per episode:
success, steps, the cube grasped first, A's centre relative to B's when A left the grasp
(height above B's and distance in the table's plane [m]; the demos set A down 3 mm above the
table, its centre 4.3 cm from B's), and at the end: A upright or tipped, how far B was
pushed in the plane [m], the hand's closest approach to C [m]. A summary sorts the failures
(:func:`failure_kind`) and compares A's release height in successes and failures.
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
import torch
from _followed import Followed

from mimicgen_pipe import backends
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.learn.evaluation import EPISODES_PER_BLOCK, evaluation_seed, rollout
from mimicgen_pipe.learn.policy import COMPONENTS
from mimicgen_pipe.learn.training import load_rollout_policy
from mimicgen_pipe.tasks.maniskill.stack_pyramid import NEAR

TASK = "stack_pyramid"
HIGH = 0.01  # [m] A let go this far above B's height or more: dropped, not set down
UPRIGHT = 0.5  # A's z axis' world z below this: A lies on a side


def failure_kind(row: dict) -> str:
    """What a failed episode ``row`` (as :func:`episode` returns) went wrong at first."""
    if row["first_grasped"] == "cubeC":
        return "took C before A"
    if row["first_grasped"] is None:
        return "grasped no cube"
    if row["a_release_height_m"] is None:
        return "never let go of A"
    if row["a_release_height_m"] >= HIGH or row["a_upright"] < UPRIGHT:
        return "dropped A from above 1 cm or tipped it"
    if row["a_end_distance_m"] > NEAR:
        return "A set down too far from B"
    if row["hand_to_c_min_m"] > 0.03:
        return "A beside B, the hand never at C"
    return "C grasped or touched, not set on the pair"


class _Follow:
    """Reads the scene after the reset and after every step of a rollout (poses world, [m])."""

    def __init__(self) -> None:
        self.b0: np.ndarray | None = None
        self.first: str | None = None
        self.held_a = False
        self.release: np.ndarray | None = None
        self.closest_c = np.inf

    def __call__(self, env) -> None:
        poses = env.object_poses()
        if self.b0 is None:  # the reset: where B starts
            self.b0 = poses["cubeB"][:2, 3].copy()
            return
        signals = env.subtask_signals()
        for cube in ("cubeA", "cubeC"):
            if self.first is None and signals[f"grasp_{cube}"]:
                self.first = cube
        if signals["grasp_cubeA"]:
            self.held_a = True
        elif self.held_a and self.release is None:
            self.release = poses["cubeA"][:3, 3] - poses["cubeB"][:3, 3]
        hand = env.eef_pose()[:3, 3]
        self.closest_c = min(self.closest_c, float(np.linalg.norm(hand - poses["cubeC"][:3, 3])))


def episode(env, policy, seed: int, variant: str, horizon: int, objects) -> dict:
    """One rollout as the evaluate stage runs it (:func:`mimicgen_pipe.learn.evaluation.rollout`),
    followed cube by cube (poses world, [m])."""
    follow = _Follow()
    r = rollout(Followed(env, follow), policy, seed, variant, horizon, objects)
    poses = env.object_poses()
    ab = poses["cubeA"][:3, 3] - poses["cubeB"][:3, 3]
    release = follow.release
    height, distance = (None, None) if release is None else (release[2], np.hypot(*release[:2]))
    return {
        "seed": seed,
        "success": r.success,
        "steps": r.steps,
        "first_grasped": follow.first,
        "a_release_height_m": None if height is None else round(float(height), 4),
        "a_release_distance_m": None if distance is None else round(float(distance), 4),
        "a_end_distance_m": round(float(np.hypot(*ab[:2])), 4),
        "a_upright": round(float(poses["cubeA"][2, 2]), 3),
        "b_pushed_m": round(float(np.linalg.norm(poses["cubeB"][:2, 3] - follow.b0)), 4),
        "hand_to_c_min_m": round(follow.closest_c, 4),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, nargs="+", help="checkpoints of the train stage")
    p.add_argument("--variant", default="D0")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--component", default="drawn", choices=COMPONENTS)
    p.add_argument("--out", type=Path, help="a JSON file with every episode")
    args = p.parse_args()
    if args.out is not None and args.out.exists():  # before any work; nothing is replaced
        p.error(f"--out {args.out}: already exists; remove it or name another file")
    spec = backends.task_spec("maniskill", TASK)
    backends.check_variant(spec, args.variant)
    torch.set_num_threads(1)  # as the evaluate stage's workers: the same sums
    policies = {path: load_rollout_policy(path, args.component) for path in args.policy}
    env = backends.make_env("maniskill", TASK)
    seed0 = load_params().evaluate.seed
    seeds = [evaluation_seed(seed0, args.variant, i) for i in range(args.episodes)]
    rows = []
    for path, policy in policies.items():
        for i, seed in enumerate(seeds):
            if i % EPISODES_PER_BLOCK == 0:  # the stage's blocks: a rollout depends on the
                env.rebuild()  # scene's history since its last rebuild
            row = {"policy": path} | episode(
                env, policy, seed, args.variant, spec.horizon, spec.objects
            )
            rows.append(row)
            print(row, flush=True)
    env.close()
    failed = [r for r in rows if not r["success"]]
    print(f"{len(rows) - len(failed)} of {len(rows)} succeeded; failures:")
    for kind, n in Counter(failure_kind(r) for r in failed).most_common():
        print(f"  {n:4d}  {kind}")
    for name, group in (("successes", [r for r in rows if r["success"]]), ("failures", failed)):
        heights = [r["a_release_height_m"] for r in group if r["a_release_height_m"] is not None]
        if heights:
            q = np.quantile(heights, [0.5, 0.9]) * 1000
            print(
                f"A let go in {name}: median {q[0]:.1f} mm above B's height, 90 % below "
                f"{q[1]:.1f} mm; {sum(h >= HIGH for h in heights)} of {len(heights)} from "
                f"{HIGH * 1000:.0f} mm or more; {sum(r['a_upright'] < UPRIGHT for r in group)} "
                "end with A tipped"
            )
    if args.out is not None:
        args.out.write_text(json.dumps({"episodes": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
