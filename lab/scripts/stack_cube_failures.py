"""Where a stack_cube policy's failed rollouts end, against the two success tests: ManiSkill's
(A on B, released and static) and robosuite's (A lifted, released, touching B).

    python lab/scripts/stack_cube_failures.py \\
        --policy data/policies/stack_cube_D0/seed0/epoch00200.pt [more .pt] \\
        [--episodes 50] [--variant D0] [--horizon 200] [--out failures.json]

Rolls each checkpoint out on the evaluate stage's first scenes of the variant as the stage
does (its seeds, blocks and torch threads, in one process: the same rollouts) and follows
each episode step by step: whether the hand ever held A, the first step A sat on B by
StackCube's test of position (centres within the half diagonal + 5 mm in xy, 4 cm ± 5 mm in
z), the first step it sat there released (robosuite's test, approximately: on B stands for
lifted and touching), and how the episode ends: A's centre against B's at the last step
(xy distance and height above resting on B, mm, world frame), the hand's path over the
last 50 steps (mm), the steps A was held within 1 cm of B's axis, the step A was first
held and the step from which the hand moved less than 1 mm a step to the end. A summary sorts the
failures (:func:`failure_kind`) and says where the failed ones ended.
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
from mimicgen_pipe.learn.training import load_rollout_policy

TASK = "stack_cube"
CUBE = 0.04  # [m] StackCube's cube edge: A rests on B with its centre this far above B's


def failure_kind(row: dict) -> str:
    """What a failed episode ``row`` (as :func:`episode` returns) went wrong at first."""
    if not row["held_a"]:
        return "never grasped A"
    if row["first_on"] < 0:
        return "A never on B"
    if row["first_released_on"] < 0:
        return "A on B, never let go there"
    if row["end_on"] and not row["end_held"]:
        return "A on B and released at the end, not still (ManiSkill's test only)"
    if row["end_on"]:
        return "A released on B, taken up again"
    return "A released on B, then off it"


class _Follow:
    """Reads the scene after the reset and after every step of a rollout."""

    def __init__(self) -> None:
        self.t = -1
        self.held_a = False
        self.first_on = -1
        self.first_released_on = -1
        self.first_held = -1
        self.held_over_b = 0  # steps A was held within 1 cm of B's axis
        self.hand: list[np.ndarray] = []  # the hand's position [m, world] after each step

    def __call__(self, env) -> None:
        self.t += 1
        s = env.subtask_signals()
        obj = env.object_poses()
        self.hand.append(env.eef_pose()[:3, 3].copy())  # poses are 4x4 matrices
        over = np.linalg.norm(obj["cubeA"][:2, 3] - obj["cubeB"][:2, 3]) < 0.01
        self.held_over_b += int(bool(s["grasp_cubeA"]) and over)
        if s["grasp_cubeA"] and not self.held_a:
            self.first_held = self.t
        self.held_a |= bool(s["grasp_cubeA"])
        if s["cubeA_on_cubeB"] and self.first_on < 0:
            self.first_on = self.t
        if s["cubeA_on_cubeB"] and not s["grasp_cubeA"] and self.first_released_on < 0:
            self.first_released_on = self.t


def episode(env, policy, seed: int, variant: str, horizon: int, objects) -> dict:
    follow = _Follow()
    r = rollout(Followed(env, follow), policy, seed, variant, horizon, objects)
    s = env.subtask_signals()
    a, b = (env.object_poses()[k][:3, 3] for k in ("cubeA", "cubeB"))
    moved = np.linalg.norm(np.diff(np.asarray(follow.hand), axis=0), axis=1)  # [m] per step
    # the hand's last still stretch: from this step on it moves less than 1 mm per step
    still_from = len(moved) - int(np.argmax(moved[::-1] >= 0.001)) if moved.max() >= 0.001 else 0
    return {
        "seed": seed,
        "success": r.success,
        "steps": r.steps,
        "held_a": follow.held_a,
        "first_on": follow.first_on,
        "first_released_on": follow.first_released_on,
        "end_on": bool(s["cubeA_on_cubeB"]),
        "end_held": bool(s["grasp_cubeA"]),
        "end_a_from_b_xy_mm": round(float(np.linalg.norm(a[:2] - b[:2])) * 1000, 1),
        "end_a_above_rest_mm": round(float(a[2] - b[2] - CUBE) * 1000, 1),
        "hand_path_last50_mm": round(float(moved[-50:].sum()) * 1000, 1),
        "held_over_b_steps": follow.held_over_b,
        "first_held": follow.first_held,
        "still_from": still_from,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True, nargs="+", help="checkpoints of the train stage")
    p.add_argument("--variant", default="D0")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--horizon", type=int, default=None, help="default: the task's")
    p.add_argument("--out", type=Path, help="a JSON file with every episode")
    args = p.parse_args()
    if args.out is not None and args.out.exists():  # before any work; nothing is replaced
        p.error(f"--out {args.out}: already exists; remove it or name another file")
    spec = backends.task_spec("maniskill", TASK)
    backends.check_variant(spec, args.variant)
    horizon = args.horizon or spec.horizon
    torch.set_num_threads(1)  # as the evaluate stage's workers: the same sums
    policies = {path: load_rollout_policy(path) for path in args.policy}
    env = backends.make_env("maniskill", TASK)
    seed0 = load_params().evaluate.seed
    seeds = [evaluation_seed(seed0, args.variant, i) for i in range(args.episodes)]
    rows = []
    for path, policy in policies.items():
        for i, seed in enumerate(seeds):
            if i % EPISODES_PER_BLOCK == 0:  # the stage's blocks: a rollout depends on the
                env.rebuild()  # scene's history since its last rebuild
            row = {"policy": path} | episode(env, policy, seed, args.variant, horizon, spec.objects)
            rows.append(row)
            print(row, flush=True)
    env.close()
    failed = [r for r in rows if not r["success"]]
    robosuite = sum(r["success"] or r["first_released_on"] >= 0 for r in rows)
    print(
        f"{len(rows) - len(failed)} of {len(rows)} succeeded (ManiSkill's test); "
        f"{robosuite} had A released on B at some step (robosuite's, approximately)"
    )
    for kind, n in Counter(failure_kind(r) for r in failed).most_common():
        print(f"  {n:4d}  {kind}")
    late = [r["first_released_on"] for r in failed if r["first_released_on"] >= 0]
    if late:
        print(f"failures with A released on B: first at step {min(late)}–{max(late)} of {horizon}")
    for r in failed:
        print(
            f"  {failure_kind(r)}: A {r['end_a_from_b_xy_mm']} mm from B's axis, "
            f"{r['end_a_above_rest_mm']} mm above resting on B, held over B "
            f"{r['held_over_b_steps']} steps; hand moved {r['hand_path_last50_mm']} mm in the "
            f"last 50 steps; A held from step {r['first_held']}, hand still from {r['still_from']}"
        )
    if args.out is not None:
        args.out.write_text(json.dumps({"horizon": horizon, "episodes": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
