"""Source demos on ManiSkill: the motion-planning demonstrator and trajectory files.

ManiSkill's motion planners drive ``pd_joint_pos``; ManiSkill's own ``replay_trajectory``
converts their trajectories to ``pd_ee_delta_pose``. A user's file goes through the same
reader: a ``.h5`` with its ``.json`` beside it, as ManiSkill's RecordEpisode writes them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from tqdm import tqdm

from mimicgen_pipe.backends import load_task
from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.core import plain_files
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.interrupts import child_environment, die_with_parent
from mimicgen_pipe.core.yamlfile import read_text

CONTROL_MODE = "pd_ee_delta_pose"


@dataclass(frozen=True)
class TrajectoryFileEpisode:
    """One episode of a trajectory file: its reset seed, actions (T, 7) float32 and the
    ManiSkill state dict at the first step (name -> (1, D) arrays)."""

    name: str
    seed: int
    actions: np.ndarray
    initial_state: dict


def _initial_state(group: h5py.Group) -> dict:
    out: dict = {}
    for kind in ("actors", "articulations"):
        out[kind] = {n: np.asarray(d[0:1], dtype=np.float32) for n, d in group[kind].items()}
    return out


def _integer(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _mapping(meta_path: Path, value: object, key: str) -> dict:
    if not isinstance(value, dict):
        raise InputError(f"{meta_path}: {key}: expected a JSON object, got {_short(value)}")
    return value


def _short(value: object) -> str:
    text = json.dumps(value) if isinstance(value, (dict, list, str)) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def read_trajectory_meta(meta_path: Path) -> tuple[dict, list[tuple[int, int]]]:
    """The ``.json`` beside a trajectory file: its env_info, and (episode_id, reset seed) of
    every episode in file order (seed -1 when it has none). Raises InputError naming the
    file and key when the file is not a regular file of at most plain_files.JSON_LIMIT
    bytes of UTF-8 JSON, not an object, or an episode's id or seed is missing, not an
    integer, given twice or (a seed) outside plain_files.SEED_RANGE."""
    text = read_text(meta_path, "trajectory .json", plain_files.JSON_LIMIT)
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{meta_path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from exc
    meta = _mapping(meta_path, meta, "top level")
    env_info = _mapping(meta_path, meta.get("env_info", {}), "env_info")
    _mapping(meta_path, env_info.get("env_kwargs", {}), "env_info.env_kwargs")
    listed = meta.get("episodes", [])
    if not isinstance(listed, list):
        raise InputError(f"{meta_path}: episodes: expected a JSON list, got {_short(listed)}")
    episodes: list[tuple[int, int]] = []
    seen: set[int] = set()
    for i, ep in enumerate(listed):
        ep = _mapping(meta_path, ep, f"episodes[{i}]")
        if "episode_id" not in ep:
            raise InputError(f"{meta_path}: episodes[{i}]: no episode_id (its traj_<id> group)")
        ep_id = ep["episode_id"]
        if not _integer(ep_id) or ep_id < 0:
            raise InputError(
                f"{meta_path}: episodes[{i}].episode_id: expected an integer >= 0, got "
                f"{_short(ep_id)}"
            )
        if ep_id in seen:
            raise InputError(f"{meta_path}: episodes[{i}].episode_id: {ep_id} listed twice")
        # ManiSkill's RecordEpisode writes episode_seed; older files only reset_kwargs.seed
        reset_kwargs = _mapping(
            meta_path, ep.get("reset_kwargs") or {}, f"episodes[{i}].reset_kwargs"
        )
        key = "episode_seed" if "episode_seed" in ep else "reset_kwargs.seed"
        seed = ep.get("episode_seed", reset_kwargs.get("seed"))
        if seed is None:
            seed = -1
        if not _integer(seed):
            raise InputError(
                f"{meta_path}: episodes[{i}].{key}: expected an integer, got {_short(seed)}"
            )
        plain_files.check_seed(seed, f"{meta_path}: episodes[{i}].{key}")
        seen.add(ep_id)
        episodes.append((ep_id, seed))
    return env_info, episodes


def read_trajectory_file(
    path: str | os.PathLike, task: str, allow_empty: bool = False
) -> list[TrajectoryFileEpisode]:
    """Read and check every episode of a ManiSkill trajectory file before any simulation.
    Raises InputError naming the file and key for an unreadable, broken or not plain .h5
    or .json (mimicgen_pipe.core.plain_files), a top-level name other than traj_<n>, a wrong
    control mode or env, a missing key, a wrong action or state shape or dtype, a
    non-finite value, or (unless ``allow_empty``) no episodes."""
    path = Path(path)
    meta_path = path.with_suffix(".json")
    plain_files.regular_file(path, "trajectory file")
    if not meta_path.exists():
        raise InputError(f"{meta_path}: the .json written beside the .h5 is missing")
    env_info, listed = read_trajectory_meta(meta_path)
    mode = env_info.get("env_kwargs", {}).get("control_mode")
    if mode != CONTROL_MODE:
        raise InputError(
            f"{meta_path}: env_info.env_kwargs.control_mode is {mode!r}, expected {CONTROL_MODE!r} "
            "(convert with python -m mani_skill.trajectory.replay_trajectory -c pd_ee_delta_pose)"
        )
    spec = load_task("maniskill", task)
    if env_info.get("env_id") not in (spec.env_id, spec.base_env_id):
        raise InputError(
            f"{meta_path}: env_info.env_id is {env_info.get('env_id')!r}, expected "
            f"{spec.base_env_id!r} for task {task}"
        )
    episodes = []
    with plain_files.open_hdf5(path, "trajectory file") as f:
        plain_files.numbered(list(f), "traj_", path, "")
        for ep_id, seed in listed:
            name = f"traj_{ep_id}"
            try:
                episodes.append(_read_episode(path, f, name, seed))
            except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
                # a damaged group or dataset, or one of strings where numbers belong
                raise InputError(f"{path}: {name}: unreadable ({exc})") from exc
    if not episodes and not allow_empty:
        raise InputError(f"{path}: no episodes")
    return episodes


def _read_episode(path: Path, f: h5py.File, name: str, seed: int) -> TrajectoryFileEpisode:
    """One episode group of a trajectory file, checked (InputError naming the key): shapes
    and dtypes from the file's declarations before anything is read."""
    if not isinstance(f.get(name), h5py.Group):
        raise InputError(f"{path}: {name} listed in the .json but missing")
    g = f[name]
    for key, kind in (
        ("actions", h5py.Dataset),
        ("env_states/actors", h5py.Group),
        ("env_states/articulations", h5py.Group),
    ):
        if not isinstance(g.get(key), kind):
            raise InputError(f"{path}: {name}/{key} missing")
    steps = plain_files.check_float_array(g["actions"], f"{path}: {name}/actions", 7)
    for key in ("env_states/actors", "env_states/articulations"):
        for n, d in g[key].items():
            where = f"{path}: {name}/{key}/{n}"
            if not isinstance(d, h5py.Dataset):
                raise InputError(f"{where} is a group, expected a dataset ({steps + 1}, D)")
            if plain_files.check_float_array(d, where) != steps + 1:
                raise InputError(f"{where} has shape {d.shape}, expected ({steps + 1}, D)")
    actions = np.asarray(g["actions"], dtype=np.float32)
    state = _initial_state(g["env_states"])
    flat = [actions] + [v for d in state.values() for v in d.values()]
    if not all(np.isfinite(a).all() for a in flat):
        raise InputError(f"{path}: {name}: NaN or infinite action or state")
    return TrajectoryFileEpisode(name, seed, actions, state)


def run_motion_planner(
    task: str, agent_uid: str, num_demos: int, seed: int, out_dir: Path, max_tries: int
) -> tuple[Path, int, int]:
    """Run the task's motion-planning demonstrator with ManiSkill agent ``agent_uid`` until
    ``num_demos`` successes (or ``max_tries`` seeds), keeping successes only, then convert
    to pd_ee_delta_pose.
    Returns (converted .h5, successful plans, failed plans)."""
    # The planners and the converter run in a child process: mplib and the converter's
    # multiprocessing are kept out of the stage's own process.
    code = (
        "import sys; from mimicgen_pipe.backends.maniskill.source import _plan_child; "
        "print(_plan_child(*sys.argv[1:]))"
    )
    args = [task, agent_uid, str(num_demos), str(seed), str(out_dir), str(max_tries)]
    planned, failed = _run_planner([sys.executable, "-c", code, *args], task, num_demos)
    raw = out_dir / "planned.h5"
    # ManiSkill's converter, in a child that has registered the env the demos were recorded in
    convert = (
        "import sys; from mimicgen_pipe.backends.maniskill.source import _convert_child; "
        "_convert_child(sys.argv[1], sys.argv[2:])"
    )
    conv = subprocess.run(
        [
            sys.executable,
            "-c",
            convert,
            task,
            "--traj-path",
            str(raw),
            "-c",
            CONTROL_MODE,
            "-o",
            "none",
            "--save-traj",
            "-b",
            "physx_cpu",
        ],
        capture_output=True,
        text=True,
        check=False,
        env=child_environment(),
    )
    if conv.returncode != 0:
        raise RuntimeError(f"conversion to {CONTROL_MODE} failed:\n{conv.stderr[-4000:]}")
    converted = sorted(out_dir.glob(f"planned.*{CONTROL_MODE}*.h5"))
    if not converted:
        raise RuntimeError(f"conversion wrote no file in {out_dir}")
    return converted[0], planned, failed


# the line the planner's child prints after each seed it tried: "<prefix> <kept> <failed>"
PLANNED = "mimicgen-pipe planned:"


def planned_counts(line: str) -> tuple[int, int] | None:
    """(kept, failed) plans of a progress line of the planner's child; None for any other
    line (what the planners print themselves, the child's result)."""
    words = line.removeprefix(PLANNED).split() if line.startswith(PLANNED) else []
    if len(words) != 2 or not all(w.isdigit() for w in words):
        return None
    return int(words[0]), int(words[1])


def follow_planner(lines: Iterable[str], bar: tqdm) -> str:
    """The last line of the planner's child's output ``lines`` other than a progress line
    (its result, "<kept> <failed>"), after moving ``bar`` (of demos kept) with each
    progress line."""
    result = ""
    for line in lines:
        if (counts := planned_counts(line)) is not None:
            bar.update(counts[0] - bar.n)
            bar.set_postfix(failed=counts[1])  # the bar counts the demos kept
        elif line.strip():
            result = line
    return result


def _run_planner(cmd: list[str], task: str, num_demos: int) -> tuple[int, int]:
    """Run the planner's child ``cmd`` with a bar of the demos it has kept: its (kept,
    failed) plans. Its stderr goes to a file, so that a full pipe never stops it."""
    bar = tqdm(total=num_demos, desc=f"source {task}: planning", unit="demo", file=sys.stderr)
    with bar, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=child_environment()
        )
        try:
            result = follow_planner(proc.stdout or (), bar)
            code = proc.wait()
        except BaseException:  # an interrupted stage: the child goes with it
            proc.kill()
            proc.wait()
            raise
        if code != 0:
            err.seek(0)
            raise RuntimeError(f"motion planning failed:\n{err.read()[-4000:]}")
    kept, failed = (int(w) for w in result.split())
    return kept, failed


def demo_env_id(task: ManiSkillTask) -> str:
    """The env the demonstrator records in: the task's own (its scene, its D0 reset, its
    success) for a demonstrator of the task's own in a scene or with a success test of the
    task's own, or for geometry of its own (env_attributes), else ManiSkill's env."""
    if task.env_attributes or (callable(task.planner) and task.task_success):
        from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv

        return ManiSkillEnv.env_id_for(task)
    return task.base_env_id


def _convert_child(task: str, args: list[str]) -> None:
    die_with_parent()
    from mani_skill.trajectory import replay_trajectory

    demo_env_id(load_task("maniskill", task))  # registers the task's env where it is used
    replay_trajectory.main(replay_trajectory.parse_args(args))


def _plan_child(
    task: str, agent_uid: str, num_demos: str, seed: str, out_dir: str, max_tries: str
) -> str:
    die_with_parent()
    os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401  registers the tasks
    from mani_skill.examples.motionplanning.panda.run import MP_SOLUTIONS
    from mani_skill.utils.wrappers.record import RecordEpisode

    spec = load_task("maniskill", task)
    env = gym.make(
        demo_env_id(spec),
        obs_mode="none",
        control_mode="pd_joint_pos",
        sim_backend="physx_cpu",
        render_backend="none",
        robot_uids=agent_uid,
        **spec.env_kwargs,
    )
    env = RecordEpisode(
        env,
        output_dir=out_dir,
        trajectory_name="planned",
        save_video=False,
        source_type="motionplanning",
        record_reward=False,
        save_on_reset=False,
    )
    solve = (
        spec.planner if callable(spec.planner) else MP_SOLUTIONS[spec.planner or spec.base_env_id]
    )
    kept = failed = 0
    for s in range(int(seed), int(seed) + int(max_tries)):
        try:
            res = solve(env, seed=s)
        except Exception:  # a planner exception is a failed demo, as in ManiSkill's runner
            res = -1
        ok = res != -1 and bool(res[-1]["success"].item())
        env.flush_trajectory(save=ok)
        kept, failed = kept + ok, failed + (not ok)
        print(PLANNED, kept, failed, flush=True)  # the stage's progress bar
        if kept == int(num_demos):
            break
    env.close()
    return f"{kept} {failed}"


def state_for_env(env, episode: TrajectoryFileEpisode, path: str | os.PathLike) -> dict:
    """An episode's first state dict with the names and widths of ``env``'s state dict:
    InputError naming the file ``path``, the episode and what was expected for an actor or
    articulation the env has not, or a state of another width. A file recorded with another
    Panda variant (e.g. panda_wristcam: same arm, plus a camera) is mapped onto this env's
    robot when the articulation state has the same size. Parts of the env the file does
    not name keep their state."""
    # as trajectory.state_layout reads it (that module brings the exporters in)
    env_state = env.unwrapped.get_state_dict()
    widths = {(k, n): int(v.shape[-1]) for k in ("actors", "articulations")
              for n, v in env_state[k].items()}  # fmt: skip
    robot = env.unwrapped.agent.robot.name
    arts = episode.initial_state["articulations"]
    rename = {n: robot for n in arts} if robot not in arts and len(arts) == 1 else {}
    out: dict = {"actors": {}, "articulations": {}}
    for kind, parts in episode.initial_state.items():
        for name, value in parts.items():
            where = f"{path}: {episode.name}/env_states/{kind}/{name}"
            key = (kind, rename.get(name, name))
            if key not in widths:
                known = ", ".join(n for k, n in widths if k == kind)
                raise InputError(
                    f"{where}: the {env.spec.name} scene with {robot!r} has no such "
                    f"{kind[:-1]}; expected one of: {known}"
                )
            if value.shape[-1] != widths[key]:
                raise InputError(
                    f"{where}: {value.shape[-1]} values per step, expected {widths[key]} "
                    f"({key[1]} in the {env.spec.name} scene)"
                )
            out[kind][key[1]] = value
    return out


def initial_state(env, state: dict) -> np.ndarray:
    """The env's flat state once ``state`` (state_for_env's) is set."""
    import torch

    env.set_state_dict({k: {n: torch.as_tensor(v) for n, v in d.items()} for k, d in state.items()})
    return env.get_state()


def source_episodes(env, num_demos: int, seed: int, from_file: str | None, work_dir: Path):
    """The motion-planning demonstrator's demos from reset seeds seed, seed + 1, ... (or
    ``from_file``'s) as SourceEpisodes, the number dropped (failed plans, and plans
    ManiSkill's converter could not turn into pd_ee_delta_pose), and the seeds tried."""
    from mimicgen_pipe.core.contracts import SourceEpisode

    def episodes(eps: list[TrajectoryFileEpisode], path: str | os.PathLike) -> list:
        states = [state_for_env(env, ep, path) for ep in eps]  # every one checked first
        return [SourceEpisode(ep.seed, initial_state(env, s), ep.actions)
                for ep, s in zip(eps, states, strict=True)]  # fmt: skip

    if from_file is not None:
        eps = read_trajectory_file(from_file, env.spec.name)[:num_demos]
        return episodes(eps, from_file), 0, 0
    traj_file, planned, failed = run_motion_planner(
        env.spec.name, env.agent_uid, num_demos, seed, work_dir, 10 * num_demos
    )
    # the converter may keep none of the plans
    converted = read_trajectory_file(traj_file, env.spec.name, allow_empty=True)
    # ManiSkill 3.0.1's converter puts the steps of the plans it failed to convert in front
    # of the next plan it converts, from the first failed plan's initial state, with an
    # uninitialised action at each join: such an episode is not its seed's demo (and is not
    # the same from one run to the next), so it is dropped as a failed conversion
    starts = planned_initial_states(work_dir / "planned.h5")
    kept = [ep for ep in converted if _same_state(ep.initial_state, starts[ep.seed])]
    return episodes(kept, traj_file), failed + planned - len(kept), planned + failed


def planned_initial_states(path: Path) -> dict[int, dict]:
    """The initial state dict of every episode of the planner's trajectory file, by seed."""
    meta = json.loads(path.with_suffix(".json").read_text())
    with h5py.File(path, "r") as f:
        return {
            int(ep["episode_seed"]): _initial_state(f[f"traj_{ep['episode_id']}"]["env_states"])
            for ep in meta["episodes"]
        }


def _same_state(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[k].keys() == b[k].keys() and all(np.array_equal(a[k][n], b[k][n]) for n in a[k])
        for k in a
    )
