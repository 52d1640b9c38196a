"""ManiSkill's stock step vs the lean step (maniskill.lean_step), StackCube, one process, one
run: ms per control step, seconds per generation attempt, the physics floor, the generator's
overhead, and seconds per policy-evaluation episode; written to metrics/benchmarks/lean_step.json.

    python benchmarks/lean_step.py [--attempts 48] [--variant D0]
        [--policy data/policies/stack_cube_D0/seed0/epoch00200.pt] [--episodes 10]

Both envs generate the same attempts (from the stores `dvc repro` writes), in alternating
blocks on rebuilt scenes as the generate stage runs them, so machine load falls on both
alike; the script checks that both paths give the same steps. The physics floor is what
any step of these attempts must pay: the PhysX substeps plus the controller's IK solve,
timed inside the lean step while it steps the attempts' actions again.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _machine import figures_path, machine

import envs
from mimicgen_pipe.evaluation import evaluation_seed, rollout
from mimicgen_pipe.generation import GenerationConfig, run_attempt
from mimicgen_pipe.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos
from mimicgen_pipe.store import read_store

TASK = "stack_cube"
# the official MimicGen code's s per Stack D0 attempt, measured once on an earlier 2-core
# machine: not side by side with a run of this script, so its ratio is approximate
MIMICGEN_S_PER_ATTEMPT = (2.0, 2.3)
OUT = figures_path(__file__)


class Timed:
    """Wraps one method of an object, adding up its wall time."""

    def __init__(self, target, method: str) -> None:
        self.target, self.seconds, self.calls = target, 0.0, 0
        self._method = getattr(target, method)
        setattr(self, method, self._call)

    def _call(self, *args, **kwargs):
        t0 = time.perf_counter()
        out = self._method(*args, **kwargs)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out


def raw_stepping(env, attempts, variant: str, floor: bool = False) -> tuple[float, int, dict]:
    """Seconds to step every attempt's actions from its reset (resets excluded), steps, and
    with ``floor`` the seconds inside PhysX substeps and IK solves of the lean step."""
    seconds, steps, parts = 0.0, 0, {"physics": 0.0, "ik": 0.0}
    for b in range(0, len(attempts), ATTEMPTS_PER_BLOCK):
        env.rebuild()
        if floor:
            lean = env._lean  # a rebuild makes a new one
            px, ik = Timed(lean._px, "step"), Timed(lean._pmodel, "compute_inverse_kinematics")
            lean._px, lean._pmodel = px, ik
        for a in attempts[b : b + ATTEMPTS_PER_BLOCK]:
            env.reset(seed=a.seed, variant=variant)
            t0 = time.perf_counter()
            for action in a.steps["actions"]:
                env.step(action)
            seconds += time.perf_counter() - t0
            steps += len(a.steps["actions"])
        if floor:
            parts["physics"] += px.seconds
            parts["ik"] += ik.seconds
    return seconds, steps, parts


def evaluation(env, policy_path: str, episodes: int, variant: str) -> tuple[float, list]:
    from mimicgen_pipe.training import load_rollout_policy

    policy = load_rollout_policy(policy_path)
    spec = env.spec
    env.rebuild()
    t0 = time.perf_counter()
    out = [
        rollout(env, policy, evaluation_seed(0, variant, i), variant, spec.horizon, spec.objects)
        for i in range(episodes)
    ]
    return time.perf_counter() - t0, out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attempts", type=int, default=48)
    p.add_argument("--variant", default="D0")
    p.add_argument("--parsed", default=f"data/pose_noise/{TASK}.zarr")
    p.add_argument("--policy", default=f"data/policies/{TASK}_D0/seed0/epoch00200.pt")
    p.add_argument("--episodes", type=int, default=10, help="policy rollouts per path")
    args = p.parse_args()
    spec = envs.task_spec("maniskill", TASK)
    sources = source_demos(read_store(args.parsed, ["target_pose"]), spec.objects)
    paths = {"stock": False, "lean": True}
    env = {name: envs.make_env("maniskill", TASK, lean_step=lean) for name, lean in paths.items()}
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    seconds = dict.fromkeys(paths, 0.0)
    attempts: dict[str, list] = {name: [] for name in paths}
    # the time inside env.step while generating, apart from the generator's own work
    in_step = {name: Timed(env[name], "step") for name in paths}
    in_reset = {name: Timed(env[name], "reset") for name in paths}
    for name in paths:
        env[name].step = in_step[name].step
        env[name].reset = in_reset[name].reset
    for b in range(0, len(seeds), ATTEMPTS_PER_BLOCK):
        for name in paths:
            env[name].rebuild()
            t0 = time.perf_counter()
            for seed in seeds[b : b + ATTEMPTS_PER_BLOCK]:
                attempts[name].append(
                    run_attempt(env[name], sources, spec, GenerationConfig(), args.variant, seed)
                )
            seconds[name] += time.perf_counter() - t0
    for name in paths:
        del env[name].step, env[name].reset  # the class's own again
    same = all(
        a.success == b.success
        and a.steps.keys() == b.steps.keys()
        and all(np.array_equal(a.steps[k], b.steps[k]) for k in a.steps)
        for a, b in zip(attempts["stock"], attempts["lean"], strict=True)
    )
    steps = sum(len(a.steps["actions"]) for a in attempts["lean"])
    dgr = 100 * np.mean([a.success for a in attempts["lean"]])
    raw = {name: raw_stepping(env[name], attempts[name], args.variant)[0] for name in paths}
    _, _, floor = raw_stepping(env["lean"], attempts["lean"], args.variant, floor=True)
    floor_s = floor["physics"] + floor["ik"]

    def ms(s: float) -> str:
        return f"{1e3 * s / steps:.3f}"

    n = args.attempts
    print(f"StackCube {args.variant}: {n} attempts, {steps} control steps, DGR {dgr:.1f} %")
    print(f"stock and lean attempts identical (every step array, bitwise): {same}")
    print("\nms per control step (the attempts' actions stepped again, resets excluded)")
    print(f"  stock env.step            {ms(raw['stock'])}")
    print(f"  lean step                 {ms(raw['lean'])}")
    print(f"  physics floor             {ms(floor_s)}  (PhysX substeps {ms(floor['physics'])}"
          f" + IK {ms(floor['ik'])})")  # fmt: skip
    print(f"  stock / lean              {raw['stock'] / raw['lean']:.2f}x")
    print(f"  lean / physics floor      {raw['lean'] / floor_s:.2f}x")
    print("\nseconds per generation attempt")
    print(f"  stock                     {seconds['stock'] / n:.3f}")
    print(f"  lean                      {seconds['lean'] / n:.3f}")
    lo, hi = MIMICGEN_S_PER_ATTEMPT
    print(f"  official MimicGen         {lo}-{hi} (its own code, Stack D0, an earlier machine)")
    print(f"  stock / lean              {seconds['stock'] / seconds['lean']:.2f}x")
    print(f"  lean / physics floor      {seconds['lean'] / floor_s:.2f}x")
    print(f"  official / lean           {lo / (seconds['lean'] / n):.1f}-"
          f"{hi / (seconds['lean'] / n):.1f}x")  # fmt: skip
    print(f"  generator / raw lean step {seconds['lean'] / raw['lean']:.2f} (overhead)")
    stepping, resetting = in_step["lean"].seconds, in_reset["lean"].seconds
    own = seconds["lean"] - stepping - resetting
    print(f"  in env.step while generating {ms(stepping)} ms per step, in env.reset"
          f" {ms(resetting)}, the generator's own work {ms(own)}")  # fmt: skip
    # what the overhead would be if the generator's own work cost nothing: env.step is
    # slower between the generator's reads than back to back, and every attempt resets
    floor_overhead = (stepping + resetting) / raw["lean"]
    print(f"  overhead with no own work  {floor_overhead:.2f} (env.step and env.reset alone)")
    figures = {
        "task": TASK,
        "variant": args.variant,
        "attempts": n,
        "control_steps": steps,
        **machine(),
        "stock_and_lean_identical": same,
        "ms_per_step_stock": round(1e3 * raw["stock"] / steps, 4),
        "ms_per_step_lean": round(1e3 * raw["lean"] / steps, 4),
        "ms_per_step_physics_floor": round(1e3 * floor_s / steps, 4),
        "seconds_per_attempt_lean": round(seconds["lean"] / n, 4),
        "seconds_per_attempt_official_earlier_machine": list(MIMICGEN_S_PER_ATTEMPT),
        "official_over_lean": [round(x / (seconds["lean"] / n), 1) for x in (lo, hi)],
        # the whole attempt (reset, selection, recording) over stepping its actions alone
        "generator_overhead": round(seconds["lean"] / raw["lean"], 3),
        "ms_per_step_in_env_step_while_generating": round(1e3 * stepping / steps, 4),
        "ms_per_step_in_env_reset_while_generating": round(1e3 * resetting / steps, 4),
        "ms_per_step_generator_own_work": round(1e3 * own / steps, 4),
        "generator_overhead_with_no_own_work": round(floor_overhead, 3),
    }
    if Path(args.policy).exists():
        ev = {n: evaluation(env[n], args.policy, args.episodes, args.variant) for n in paths}
        same_ev = [r.success for r in ev["stock"][1]] == [r.success for r in ev["lean"][1]]
        ev_steps = sum(r.steps for r in ev["lean"][1])
        print(f"\npolicy evaluation ({args.policy}, {args.episodes} episodes, {ev_steps} steps)")
        for name in paths:
            print(f"  {name:5s} s/episode           {ev[name][0] / args.episodes:.3f}")
        print(f"  stock / lean              {ev['stock'][0] / ev['lean'][0]:.2f}x")
        print(f"  same outcomes             {same_ev}")
        figures["seconds_per_episode_lean"] = round(ev["lean"][0] / args.episodes, 4)
    OUT.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"-> {OUT}")
    for e in env.values():
        e.close()


if __name__ == "__main__":
    main()
