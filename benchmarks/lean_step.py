"""Generation speed on StackCube, one process, one run: ManiSkill's stock step vs the lean
step (maniskill.lean_step) in ms per control step, seconds per generation attempt, the
physics floor, the generator's overhead, the generate stage against this benchmark, the
official MimicGen code side by side, and seconds per policy-evaluation episode; written to
metrics/benchmarks/lean_step.json.

    python benchmarks/lean_step.py [--attempts 48] [--variant D0] [--official-attempts 20]
        [--policy data/policies/stack_cube_D0/seed0/epoch00200.pt] [--episodes 10]

Both envs generate the same attempts (from the stores `dvc repro` writes), in alternating
blocks on rebuilt scenes as the generate stage runs them, so machine load falls on both
alike; the script checks that both paths give the same steps. The physics floor is what
any step of these attempts must pay: the PhysX substeps plus the controller's IK solve,
timed inside the lean step while it steps the attempts' actions again. The generate stage
then runs the same attempts with one worker, and its seconds per attempt (rebuilds
included) are set against this benchmark's.

The official code (NVlabs/mimicgen on robosuite 1.4.1, MuJoCo 2.3.2) runs where its venv
exists (``bash scripts/official_mimicgen_venv.sh``): Stack D0 attempts timed before and
after ours in the same run, so that the ratio compares the two on one machine at one time.
Without the venv the JSON says the ratio was not measured.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from _machine import figures_path, machine
from _official import NOT_MEASURED, official_venv, run_official

from mimicgen_pipe import backends
from mimicgen_pipe.data.metrics import timings_file
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.learn.evaluation import evaluation_seed, rollout
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos

TASK = "stack_cube"
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
    from mimicgen_pipe.learn.training import load_rollout_policy

    policy = load_rollout_policy(policy_path)
    spec = env.spec
    env.rebuild()
    t0 = time.perf_counter()
    out = [
        rollout(env, policy, evaluation_seed(0, variant, i), variant, spec.horizon, spec.objects)
        for i in range(episodes)
    ]
    return time.perf_counter() - t0, out


def stage_run(attempts: int, variant: str, parsed: str) -> dict:
    """The generate stage on the benchmark's attempts (the same seeds and blocks) with one
    worker, as a user runs it; its metrics JSON and its times."""
    params = yaml.safe_load(Path("params.yaml").read_text())
    params["generate"]["workers"] = 1
    with tempfile.TemporaryDirectory(prefix="lean_step-") as tmp:
        path = Path(tmp)
        (path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        cmd = [sys.executable, "-m", "mimicgen_pipe.cli", "generate", "--params",
               str(path / "params.yaml"), "--task", TASK, "--variant", variant, "--attempts",
               str(attempts), "--parsed", parsed, "--out", str(path / "g.zarr"), "--metrics",
               str(path / "g.json")]  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        metrics = json.loads((path / "g.json").read_text())
        metrics |= json.loads(timings_file(path / "g.json").read_text())
        metrics["process_seconds"] = time.perf_counter() - t0
        return metrics


def official(attempts: int) -> dict | None:
    """The official code's Stack D0 attempts in its venv, or None without the venv."""
    venv = official_venv()
    return None if venv is None or attempts == 0 else run_official(attempts, 0, venv)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attempts", type=int, default=48)
    p.add_argument("--variant", default="D0")
    p.add_argument("--parsed", default=f"data/pose_noise/{TASK}.zarr")
    p.add_argument("--official-attempts", type=int, default=20,
                   help="official MimicGen attempts before and after ours (0: none)")  # fmt: skip
    p.add_argument("--policy", default=f"data/policies/{TASK}_D0/seed0/epoch00200.pt")
    p.add_argument("--episodes", type=int, default=10, help="policy rollouts per path")
    args = p.parse_args()
    if not Path(args.parsed).exists():
        sys.exit(f"{args.parsed}: no parsed store (dvc repro pose_noise makes it)")
    official_before = official(args.official_attempts)
    spec = backends.task_spec("maniskill", TASK)
    sources = source_demos(read_store(args.parsed, ["target_pose"]), spec.objects)
    paths = {"stock": False, "lean": True}
    env = {
        name: backends.make_env("maniskill", TASK, lean_step=lean) for name, lean in paths.items()
    }
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    seconds = dict.fromkeys(paths, 0.0)
    rebuilds = dict.fromkeys(paths, 0.0)
    attempts: dict[str, list] = {name: [] for name in paths}
    # the time inside env.step while generating, apart from the generator's own work
    in_step = {name: Timed(env[name], "step") for name in paths}
    in_reset = {name: Timed(env[name], "reset") for name in paths}
    for name in paths:
        env[name].step = in_step[name].step
        env[name].reset = in_reset[name].reset
    for b in range(0, len(seeds), ATTEMPTS_PER_BLOCK):
        for name in paths:
            t0 = time.perf_counter()
            env[name].rebuild()  # as the stage's workers do before each block
            t1 = time.perf_counter()
            for seed in seeds[b : b + ATTEMPTS_PER_BLOCK]:
                attempts[name].append(
                    run_attempt(env[name], sources, spec, GenerationConfig(), args.variant, seed)
                )
            seconds[name] += time.perf_counter() - t1
            rebuilds[name] += t1 - t0
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
    stage = stage_run(args.attempts, args.variant, args.parsed)
    official_after = official(args.official_attempts)

    def ms(s: float) -> str:
        return f"{1e3 * s / steps:.3f}"

    n = args.attempts
    lean_s = seconds["lean"] / n
    with_rebuild = (seconds["lean"] + rebuilds["lean"]) / n
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
    print(f"  lean                      {lean_s:.3f}")
    per_rebuild = rebuilds["lean"] / -(-n // ATTEMPTS_PER_BLOCK)
    print(f"  lean, rebuilds included   {with_rebuild:.3f}  (a rebuild per "
          f"{ATTEMPTS_PER_BLOCK} attempts: {per_rebuild:.3f} s)")  # fmt: skip
    print(f"  stock / lean              {seconds['stock'] / seconds['lean']:.2f}x")
    print(f"  lean / physics floor      {seconds['lean'] / floor_s:.2f}x")
    print(f"  generator / raw lean step {seconds['lean'] / raw['lean']:.2f} (overhead)")
    stepping, resetting = in_step["lean"].seconds, in_reset["lean"].seconds
    own = seconds["lean"] - stepping - resetting
    print(f"  in env.step while generating {ms(stepping)} ms per step, in env.reset"
          f" {ms(resetting)}, the generator's own work {ms(own)}")  # fmt: skip
    # what the overhead would be if the generator's own work cost nothing: env.step is
    # slower between the generator's reads than back to back, and every attempt resets
    floor_overhead = (stepping + resetting) / raw["lean"]
    print(f"  overhead with no own work  {floor_overhead:.2f} (env.step and env.reset alone)")
    stage_s = stage["seconds_per_attempt_mean"]
    same_stage = stage["steps"] == steps and stage["successes"] == sum(
        a.success for a in attempts["lean"]
    )
    print(f"\ngenerate stage, 1 worker, the same {n} attempts (same steps and DGR: {same_stage})")
    print(f"  s/attempt in the worker   {stage_s:.3f}  (rebuilds included)")
    print(f"  stage / benchmark         {stage_s / with_rebuild:.3f}  (both with rebuilds)")
    print(f"  whole command             {stage['process_seconds']:.1f} s (start-up, stores)")
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
        "ms_per_step_physx": round(1e3 * floor["physics"] / steps, 4),
        "ms_per_step_ik": round(1e3 * floor["ik"] / steps, 4),
        "seconds_per_attempt_lean": round(lean_s, 4),
        "seconds_per_attempt_lean_with_rebuilds": round(with_rebuild, 4),
        "seconds_per_rebuild": round(per_rebuild, 4),
        "attempt_over_physics_floor": round(seconds["lean"] / floor_s, 3),
        # the whole attempt (reset, selection, recording) over stepping its actions alone
        "generator_overhead": round(seconds["lean"] / raw["lean"], 3),
        "ms_per_step_in_env_step_while_generating": round(1e3 * stepping / steps, 4),
        "ms_per_step_in_env_reset_while_generating": round(1e3 * resetting / steps, 4),
        "ms_per_step_generator_own_work": round(1e3 * own / steps, 4),
        "generator_overhead_with_no_own_work": round(floor_overhead, 3),
        "stage_same_attempts": same_stage,
        "seconds_per_attempt_stage": round(stage_s, 4),
        "stage_over_benchmark": round(stage_s / with_rebuild, 3),
        "stage_command_seconds": round(stage["process_seconds"], 1),
    }
    print("\nofficial MimicGen (its own code, Stack D0, this machine, this run)")
    if official_before is None or official_after is None:
        print(f"  {NOT_MEASURED}")
        figures["official"] = NOT_MEASURED
    else:
        runs = (official_before, official_after)
        off = [r["s_per_attempt"] for r in runs]
        for label, r in zip(("before ours", "after ours"), runs, strict=True):
            print(f"  {label:10s} {r['attempts']} attempts, {r['s_per_attempt']:.3f} s/attempt, "
                  f"{r['steps_per_attempt']:.1f} steps, {r['ms_per_step']:.2f} ms/step, "
                  f"reset {r['s_per_reset']:.3f} s, {r['successes']} succeeded")  # fmt: skip
        print(f"  official / lean           {min(off) / lean_s:.1f}-{max(off) / lean_s:.1f}x"
              f" per attempt, {min(off) / stage_s:.1f}-{max(off) / stage_s:.1f}x against the"
              " stage")  # fmt: skip
        figures["official"] = {"before": official_before, "after": official_after}
        figures["official_over_lean"] = [round(x / lean_s, 2) for x in (min(off), max(off))]
        figures["official_over_stage"] = [round(x / stage_s, 2) for x in (min(off), max(off))]
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
