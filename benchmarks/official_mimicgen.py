"""Times the official MimicGen generate loop (NVlabs/mimicgen on robosuite) on Stack D0.

Runs inside .venv-official (bash scripts/official_mimicgen_venv.sh builds it), never in the
project's .venv, and imports nothing of the project:

    .venv-official/bin/python benchmarks/official_mimicgen.py [--attempts 10] [--blocks 1]
        [--seed 0] [--json] [--cache-dir DIR]

MimicGen's source dataset (10 human Stack demos) is downloaded from a hub in its tutorials;
this script records its own instead, once: a scripted demonstrator stacks cube A on cube B on
robosuite Stack_D0 with OSC_POSE delta actions, the demos are written as a robomimic hdf5
(states, actions, model_file), and MimicGen's own prepare_src_dataset adds the datagen info.
The result is cached, so later runs only generate.

Each attempt is one DataGenerator.generate call, as in mimicgen/scripts/generate_dataset.py
with the Stack D0 settings of its generate_core_configs.py: reset to a new D0 scene, select a
source demo per subtask (nearest object, k=3), transform, interpolate (5 steps), execute with
action noise 0.05, check success. Only those calls are timed: env construction, the source
demos and writing datasets are not. With --blocks B the attempts run in B blocks, each on a
freshly built env. stdout carries one JSON line (after a summary, without --json); everything
the official code prints goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ENV_NAME = "Stack_D0"
SOURCE_DEMOS = 10
# bump when the recorder changes, so that a cached source dataset is not reused
RECORDER_VERSION = 1
# the settings of MimicGen's core Stack configs (scripts/generate_core_configs.py)
SELECT_SRC_PER_SUBTASK = True

Log = Callable[[str], None]


def parse_args() -> argparse.Namespace:
    """Command line."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--attempts", type=int, default=10, help="generation attempts timed")
    p.add_argument("--blocks", type=int, default=1, help="blocks, each on a rebuilt env")
    p.add_argument("--seed", type=int, default=0, help="seeds numpy and random, as MimicGen does")
    p.add_argument("--json", action="store_true", help="print only the JSON line")
    p.add_argument(
        "--cache-dir",
        type=Path,
        default=Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        / "mimicgen-official",
        help="where the source dataset is kept between runs",
    )
    a = p.parse_args()
    if a.attempts < 1 or not 1 <= a.blocks <= a.attempts:
        p.error("needs --attempts >= 1 and 1 <= --blocks <= --attempts")
    return a


def versions() -> dict[str, str]:
    """Versions of the official stack, as imported."""
    import mimicgen
    import mujoco
    import robomimic
    import robosuite

    return {
        "robosuite": robosuite.__version__,
        "mujoco": mujoco.__version__,
        "mimicgen": mimicgen.__version__,
        "robomimic": robomimic.__version__,
        "python": ".".join(map(str, sys.version_info[:3])),
    }


def env_kwargs() -> dict[str, Any]:
    """Stack_D0's constructor arguments as robomimic keeps them in env_args: no rendering and no
    camera observations (robomimic sets those flags itself when it rebuilds the env)."""
    from robosuite import load_controller_config

    return {
        "robots": ["Panda"],
        "controller_configs": load_controller_config(default_controller="OSC_POSE"),
        "control_freq": 20,
        "reward_shaping": False,
        "use_object_obs": True,
        "ignore_done": True,
        "has_renderer": False,
        "has_offscreen_renderer": False,
        "use_camera_obs": False,
    }


def scripted_demo(env, rng: np.random.Generator) -> tuple[list, list, bool]:
    """One Stack demo by a scripted OSC_POSE demonstrator: over cube A, down, grasp, lift, over
    cube B, down, release. Returns the flattened sim states before each action, the actions
    and whether the env reports success."""
    env.reset()
    sim = env.sim
    eef_site = env.robots[0].eef_site_id

    def eef() -> np.ndarray:
        return np.array(sim.data.site_xpos[eef_site])

    def cube(body: str) -> np.ndarray:
        return np.array(sim.data.body_xpos[sim.model.body_name2id(body)])

    a_body, b_body = env.cubeA.root_body, env.cubeB.root_body
    # a little spread in the demos, as human ones have
    jitter = rng.uniform(-0.004, 0.004, size=3) * np.array([1, 1, 0])
    states, actions = [], []

    def act(target: np.ndarray, grip: float) -> None:
        # P-control on the position delta; OSC_POSE scales +-1 to +-5 cm per step
        delta = np.clip((target - eef()) * 12.0, -1.0, 1.0)
        action = np.concatenate([delta, np.zeros(3), [grip]])
        states.append(np.array(sim.get_state().flatten()))
        actions.append(action)
        env.step(action)

    def go(target_fn, grip: float, tol: float, max_steps: int) -> None:
        for _ in range(max_steps):
            if np.linalg.norm(target_fn() - eef()) < tol:
                return
            act(target_fn(), grip)

    up = np.array([0.0, 0.0, 1.0])
    go(lambda: cube(a_body) + jitter + 0.08 * up, -1.0, 0.01, 60)
    go(lambda: cube(a_body) + jitter, -1.0, 0.006, 40)
    for _ in range(12):
        act(cube(a_body) + jitter, 1.0)
    go(lambda: cube(a_body) * [1, 1, 0] + (cube(b_body)[2] + 0.12) * up, 1.0, 0.01, 60)
    go(lambda: cube(b_body) * [1, 1, 0] + (cube(b_body)[2] + 0.12) * up, 1.0, 0.01, 60)
    go(lambda: cube(b_body) + 0.055 * up, 1.0, 0.008, 40)
    for _ in range(10):
        act(eef(), -1.0)
    return states, actions, bool(env._check_success())


def record_source(path: Path, n: int, seed: int, log: Log) -> None:
    """Records ``n`` successful scripted demos on Stack_D0 into a robomimic hdf5 at ``path``."""
    import h5py
    import robosuite

    kwargs = env_kwargs()
    env = robosuite.make(ENV_NAME, **kwargs)
    rng = np.random.default_rng(seed)
    np.random.seed(seed)  # robosuite's placement sampler draws from numpy's global state
    tmp = path.with_suffix(".tmp.hdf5")
    with h5py.File(tmp, "w") as f:
        data = f.create_group("data")
        kept = tries = total = 0
        while kept < n:
            tries += 1
            if tries > 4 * n:
                raise RuntimeError(f"the scripted demonstrator stacked only {kept} of {tries}")
            states, actions, success = scripted_demo(env, rng)
            if not success:
                continue
            ep = data.create_group(f"demo_{kept}")
            ep.create_dataset("states", data=np.array(states))
            ep.create_dataset("actions", data=np.array(actions))
            ep.attrs["model_file"] = env.sim.model.get_xml()
            ep.attrs["num_samples"] = len(actions)
            kept += 1
            total += len(actions)
            log(f"source demo {kept}/{n}: {len(actions)} steps")
        data.attrs["total"] = total
        # robomimic's env metadata; type 1 is robomimic's EnvType.ROBOSUITE_TYPE
        data.attrs["env_args"] = json.dumps(
            {
                "env_name": ENV_NAME,
                "env_version": robosuite.__version__,
                "type": 1,
                "env_kwargs": kwargs,
            }
        )
    env.close()
    tmp.rename(path)


def source_dataset(cache_dir: Path, log: Log) -> Path:
    """The prepared source dataset, recorded and prepared on the first run only."""
    import robosuite
    from mimicgen.scripts.prepare_src_dataset import prepare_src_dataset

    cache_dir.mkdir(parents=True, exist_ok=True)
    name = f"stack_d0_src{SOURCE_DEMOS}_r{RECORDER_VERSION}_rs{robosuite.__version__}.hdf5"
    path = cache_dir / name
    if path.exists():
        return path
    raw = cache_dir / f"raw_{name}"
    log(f"recording {SOURCE_DEMOS} source demos on {ENV_NAME} (first run only)")
    record_source(raw, SOURCE_DEMOS, seed=12345, log=log)
    prepared = cache_dir / f"prep_{name}"
    prepare_src_dataset(
        dataset_path=str(raw),
        env_interface_name="MG_Stack",
        env_interface_type="robosuite",
        output_path=str(prepared),
    )
    raw.unlink()
    prepared.rename(path)
    return path


class Timer:
    """Adds up the wall time of one method of an object, replacing it on that instance only."""

    def __init__(self, target: Any, method: str) -> None:
        self.seconds, self.calls = 0.0, 0
        inner = getattr(target, method)

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - t0
                self.calls += 1

        setattr(target, method, timed)


def run(args: argparse.Namespace, log: Log) -> dict[str, Any]:
    """Builds MimicGen's config, env, interface and generator as generate_dataset.py does, then
    times ``args.attempts`` generate calls."""
    import mimicgen.utils.file_utils as mg_file_utils
    import mimicgen.utils.robomimic_utils as mg_robomimic_utils
    from mimicgen.configs import MG_TaskSpec, config_factory
    from mimicgen.datagen.data_generator import DataGenerator
    from mimicgen.env_interfaces.base import make_interface
    from robomimic.utils.file_utils import get_env_metadata_from_dataset

    src = source_dataset(args.cache_dir, log)

    cfg = config_factory("stack", config_type="robosuite")
    cfg.experiment.source.dataset_path = str(src)
    cfg.experiment.task.name = ENV_NAME
    cfg.experiment.generation.select_src_per_subtask = SELECT_SRC_PER_SUBTASK
    cfg.experiment.seed = args.seed
    cfg.obs.camera_names = []
    gen = cfg.experiment.generation

    env_meta = get_env_metadata_from_dataset(dataset_path=str(src))
    demo_keys = mg_file_utils.get_all_demos_from_dataset(
        dataset_path=str(src),
        filter_key=cfg.experiment.source.filter_key,
        start=cfg.experiment.source.start,
        n=cfg.experiment.source.n,
    )
    interface_name, interface_type = mg_file_utils.get_env_interface_info_from_dataset(
        dataset_path=str(src), demo_keys=demo_keys
    )
    task_spec = MG_TaskSpec.from_json(json_string=cfg.task.task_spec.dump())
    generator = DataGenerator(task_spec=task_spec, dataset_path=str(src), demo_keys=demo_keys)

    random.seed(cfg.experiment.seed)
    np.random.seed(cfg.experiment.seed)

    sizes = [len(b) for b in np.array_split(np.arange(args.attempts), args.blocks)]
    block_seconds: list[float] = []
    successes = problematic = steps = step_calls = reset_calls = 0
    step_s = reset_s = 0.0
    for size in sizes:
        env = mg_robomimic_utils.create_env(
            env_meta=env_meta,
            env_class=None,
            env_name=cfg.experiment.task.name,
            robot=cfg.experiment.task.robot,
            gripper=cfg.experiment.task.gripper,
            env_meta_update_kwargs=cfg.experiment.task.env_meta_update_kwargs,
            camera_names=[],
            camera_height=cfg.obs.camera_height,
            camera_width=cfg.obs.camera_width,
            render=False,
            render_offscreen=False,
            use_image_obs=False,
            use_depth_obs=False,
        )
        interface = make_interface(
            name=interface_name, interface_type=interface_type, env=env.base_env
        )
        # robosuite compiles its numba kernels on the first controller step: not timed
        env.reset()
        env.step(np.zeros(env.action_dimension))
        step_t, reset_t = Timer(env, "step"), Timer(env, "reset")
        seconds, done = 0.0, 0
        while done < size:
            t0 = time.perf_counter()
            try:
                traj = generator.generate(
                    env=env,
                    env_interface=interface,
                    select_src_per_subtask=gen.select_src_per_subtask,
                    transform_first_robot_pose=gen.transform_first_robot_pose,
                    interpolate_from_last_target_pose=gen.interpolate_from_last_target_pose,
                    render=False,
                    video_writer=None,
                    video_skip=5,
                    camera_names=None,
                    pause_subtask=False,
                )
            except env.rollout_exceptions as e:
                # generate_dataset.py retries these without counting an attempt
                seconds += time.perf_counter() - t0
                problematic += 1
                log(f"rollout exception, retried: {e}")
                continue
            seconds += time.perf_counter() - t0
            done += 1
            successes += int(bool(traj["success"]))
            steps += int(traj["actions"].shape[0])
            log(
                f"attempt {len(block_seconds)}.{done}: success {bool(traj['success'])}, "
                f"{traj['actions'].shape[0]} steps"
            )
        block_seconds.append(seconds)
        step_s, step_calls = step_s + step_t.seconds, step_calls + step_t.calls
        reset_s, reset_calls = reset_s + reset_t.seconds, reset_calls + reset_t.calls
        env.base_env.close()

    total = sum(block_seconds)
    return {
        "task": ENV_NAME,
        "attempts": args.attempts,
        "successes": successes,
        "problematic": problematic,
        "blocks": args.blocks,
        "seed": args.seed,
        "source_demos": len(demo_keys),
        "seconds": round(total, 3),
        "block_seconds": [round(s, 3) for s in block_seconds],
        "s_per_attempt": round(total / args.attempts, 4),
        "steps_per_attempt": round(steps / args.attempts, 1),
        "ms_per_step": round(1000 * step_s / max(step_calls, 1), 3),
        "s_per_reset": round(reset_s / max(reset_calls, 1), 4),
        "versions": versions(),
    }


def main() -> None:
    args = parse_args()
    # The official code prints freely: keep stdout for the result alone.
    out = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    sys.stdout.flush()
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())

    def log(msg: str) -> None:
        print(f"[official] {msg}", file=sys.stderr, flush=True)

    result = run(args, log)
    if not args.json:
        print(
            f"official MimicGen {result['versions']['mimicgen']} on {ENV_NAME}: "
            f"{result['successes']}/{result['attempts']} successes, "
            f"{result['s_per_attempt']} s/attempt, {result['steps_per_attempt']} steps/attempt, "
            f"{result['ms_per_step']} ms/step, {result['s_per_reset']} s/reset",
            file=out,
        )
    print(json.dumps(result), file=out, flush=True)


if __name__ == "__main__":
    main()
