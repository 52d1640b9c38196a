"""Where the source stage's demos come from: the back end's demonstrator or a file format of
its own (envs/<backend>/), or a robomimic ``.hdf5`` on any back end (as the export stage
writes it), read by the robomimic exporter. Used by the source stage alone, so that no other
stage depends on an exporter."""

from __future__ import annotations

from pathlib import Path

import envs
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.registry import load

ROBOMIMIC_SUFFIXES = (".hdf5", ".hdf")


def is_robomimic_file(path: str) -> bool:
    return Path(path).suffix.lower() in ROBOMIMIC_SUFFIXES


def robomimic_demos(path: str, backend: str, task: str) -> list:
    """Every demo of the robomimic file at ``path``, checked to be of ``backend`` and
    ``task`` (RobomimicDemo: name, seed, initial_state, actions); InputError naming the file
    and key when it is not."""
    return load("mimicgen_pipe.exporters", "robomimic").read(path, backend, task)


def source_episodes(
    backend: str,
    env,
    num_demos: int,
    seed: int,
    from_file: str | None,
    work_dir: Path,
) -> tuple[list[envs.SourceEpisode], int, int]:
    """Up to ``num_demos`` source demos on ``env`` from the back end's demonstrator, drawn
    from reset seeds seed, seed + 1, ... (or ``from_file``'s: a robomimic ``.hdf5`` of this
    back end and task, e.g. one the export stage wrote, or a file format of the back end's
    own), how many the demonstrator dropped as failures, and how many seeds it tried (0 for
    a file)."""
    if from_file is None or not is_robomimic_file(from_file):
        return envs.source_episodes(backend, env, num_demos, seed, from_file, work_dir)
    demos = robomimic_demos(from_file, backend, env.spec.name)[:num_demos]
    width = env.get_state().shape[-1]
    for demo in demos:
        if demo.initial_state.shape[-1] != width:
            raise InputError(
                f"{from_file}: data/{demo.name}/states has {demo.initial_state.shape[-1]} "
                f"values per step, expected {width} (the {backend} {env.spec.name} state with "
                f"{env.robot})"
            )
    return [envs.SourceEpisode(d.seed, d.initial_state, d.actions) for d in demos], 0, 0
