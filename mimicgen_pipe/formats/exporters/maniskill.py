"""ManiSkill trajectory files (``.h5`` + ``.json``, as ManiSkill's RecordEpisode writes them),
which ``python -m mani_skill.trajectory.replay_trajectory`` replays and converts.

The arrays come from a replay of each stored episode in the simulator
(mimicgen_pipe/backends/maniskill/trajectory.py): the store holds the state before each action, a
trajectory file also the state after the last one. Two files are written: ``trajectory.h5`` with the
episodes' own ``pd_ee_delta_pose`` actions, and ``trajectory.pd_joint_pos.h5`` with the same
motion as ``pd_joint_pos`` actions, the control mode ManiSkill's converter starts from (its
``-c`` converts pd_joint_pos and pd_joint_delta_pos trajectories, not delta-pose ones).

Per episode ``traj_<i>``, as ManiSkill's RecordEpisode writes them: ``actions`` (T, A)
float32; ``env_states/actors/<name>`` (T+1, 13) and ``env_states/articulations/<name>``
(T+1, 13 + 2 dof) float32; ``obs/<key>`` (T+1, d) float32, the low-dim observations by the
store's names (mimicgen_pipe.core.observations: world frame, quaternions wxyz) before every
action and after the last (from the replay); ``rewards`` (T,) float32, the sparse success
reward (1.0 after a step that leaves the task achieved, ManiSkill's reward_mode "sparse");
``success``, ``fail`` (no task of ours has a failure state: all False), ``terminated``
(= success) and ``truncated`` (T,) bool, all from the replay. The ``.json``: ``env_info``
(env_id, env_kwargs with reward_mode "sparse" and obs_mode "state_dict", a dict of low-dim
state as obs/ holds, max_episode_steps), ``episodes`` [{episode_id, episode_seed,
reset_kwargs, control_mode, elapsed_steps, success}] and ``mimicgen_pipe``
(exporters.provenance: what made the data, the file's control mode and conventions). Replay them
with ``--use-first-env-state`` (the scene comes from the stored state; the seed alone gives
ManiSkill's D0 scene, not ours).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mimicgen_pipe.core.contracts import Replayed
from mimicgen_pipe.data.store import EpisodeStore
from mimicgen_pipe.formats import hdf5
from mimicgen_pipe.formats.exporters import PROVENANCE_KEY, provenance

FILE_NAME = "trajectory.h5"  # and its .json, and the pd_joint_pos copy of both
JOINT_FILE_SUFFIX = ".pd_joint_pos"
WRITES = rf"trajectory({re.escape(JOINT_FILE_SUFFIX)})?\.(h5|json)"
REQUIRED = ("actions", "env_state")
# ManiSkill's obs mode of a dict of low-dim state arrays, object poses included: what obs/
# holds (the store's keys, not ManiSkill's own state_dict keys; PROVENANCE_KEY says whose)
OBS_MODE = "state_dict"


def check(store: EpisodeStore, info) -> str | None:
    from mimicgen_pipe.formats.exporters import missing_keys

    backend = info.env_args.get("env_kwargs", {}).get("backend")
    if backend != "maniskill":
        return f"a {backend} store (ManiSkill trajectories need the maniskill back end)"
    if info.arms:
        return (
            f"a task with arms {', '.join(info.arms)} (ManiSkill trajectories are written "
            "for one agent's actions; export robomimic or lerobot)"
        )
    return missing_keys(store, REQUIRED) or (None if store.n_episodes else "no episodes")


def _split_states(states: np.ndarray, layout: Sequence[tuple[str, str, int]]) -> dict:
    out: dict[str, dict[str, np.ndarray]] = {"actors": {}, "articulations": {}}
    at = 0
    for kind, name, width in layout:
        out[kind][name] = states[:, at : at + width]
        at += width
    if at != states.shape[1]:
        raise ValueError(f"state layout covers {at} of {states.shape[1]} values")
    return out


def _obs_keys(data: Mapping[str, np.ndarray]) -> list[str]:
    """The low-dim observation keys of a store's (or an episode's) arrays: what obs/ holds."""
    low_dim = (k for k in data if k.startswith("obs/") and not k.endswith("_image"))
    return [k.removeprefix("obs/") for k in low_dim]


def _observations(ep: Mapping[str, np.ndarray], rep: Replayed) -> dict[str, np.ndarray]:
    """A trajectory's ``obs/<key>``, (T + 1, d) float32: the store's observation before each
    action, then the replay's after the last one."""
    keys = _obs_keys(ep)
    missing = [k for k in keys if k not in rep.last_obs]
    if missing:
        raise ValueError(f"the replay's last observation lacks {missing}")
    return {
        k: np.concatenate([ep[f"obs/{k}"], np.asarray(rep.last_obs[k])[None]]).astype(np.float32)
        for k in keys
    }


def _write_file(
    path: Path,
    store: EpisodeStore,
    replays: Sequence[Replayed],
    layout: Sequence[tuple[str, str, int]],
    env_info: dict,
    control_mode: str,
) -> None:
    seeds = store.episodes.get("seed", np.full(store.n_episodes, -1))
    episodes = []
    with hdf5.create(path) as f:
        for i, rep in enumerate(replays):
            joint = control_mode == "pd_joint_pos"
            actions = rep.joint_actions if joint else store.episode(i)["actions"]
            g = hdf5.group(f, f"traj_{i}")
            hdf5.dataset(g, "actions", data=np.asarray(actions, np.float32))
            for kind, parts in _split_states(rep.states, layout).items():
                for name, value in parts.items():
                    hdf5.dataset(g, f"env_states/{kind}/{name}", data=value)
            hdf5.dataset(g, "success", data=rep.success)
            hdf5.dataset(g, "fail", data=np.zeros(len(rep.success), bool))
            hdf5.dataset(g, "rewards", data=rep.success.astype(np.float32))
            hdf5.dataset(g, "terminated", data=rep.success)
            hdf5.dataset(g, "truncated", data=np.zeros(len(rep.success), bool))
            for key, rows in _observations(store.episode(i), rep).items():
                hdf5.dataset(g, f"obs/{key}", data=rows)
            seed = int(seeds[i])
            episodes.append(
                {
                    "episode_id": i,
                    "episode_seed": seed,
                    "reset_kwargs": {"seed": seed},
                    "control_mode": control_mode,
                    "elapsed_steps": len(rep.success),
                    "success": bool(rep.success[-1]),
                }
            )
    # rewards are the sparse success reward, which ManiSkill's reward_mode "sparse" gives;
    # obs_mode says what the file's obs hold (a replay without -o records that mode too)
    kwargs = dict(env_info["env_kwargs"], control_mode=control_mode, reward_mode="sparse")
    kwargs["obs_mode"] = OBS_MODE if _obs_keys(store.data) else "none"
    info = dict(env_info, env_kwargs=kwargs)
    meta = {"env_info": info, "source_type": "mimicgen-pipe", "episodes": episodes}
    meta[PROVENANCE_KEY] = provenance(store.attrs, control_mode=control_mode)
    path.with_suffix(".json").write_text(json.dumps(meta, indent=2))


def write(
    store: EpisodeStore,
    path: Path,
    info,
    replays: Sequence[Replayed],
    layout: Sequence[tuple[str, str, int]],
    env_info: dict,
) -> dict[str, int]:
    """``path`` (.h5, its .json beside it) with the store's own actions, and the
    pd_joint_pos copy beside it. ``replays``: one per stored episode, in order; ``layout``:
    (kind, name, width) of the flat state's parts; ``env_info``: the json's env_info. No
    figures for the metrics (no images)."""
    if len(replays) != store.n_episodes:
        raise ValueError(f"{len(replays)} replays for {store.n_episodes} episodes")
    mode = env_info["env_kwargs"]["control_mode"]
    _write_file(path, store, replays, layout, env_info, mode)
    joint = path.with_name(path.stem + JOINT_FILE_SUFFIX + path.suffix)
    _write_file(joint, store, replays, layout, env_info, "pd_joint_pos")
    return {}
