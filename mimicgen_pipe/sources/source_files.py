"""Where the source stage's demos come from: the back end's demonstrator or a file format of
its own (mimicgen_pipe/backends/<backend>/), or a robomimic ``.hdf5`` on any back end (as the export
stage writes it; mimicgen_pipe.sources.robomimic_source reads it)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mimicgen_pipe.core.contracts import Env, SourceEpisode
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.sources import robomimic_source

# a back end's demonstrator (contracts.Backend.source_episodes): (env, num_demos, first reset
# seed, source.from_file, a scratch directory) -> (demos, failures dropped, seeds tried)
Demonstrator = Callable[[Env, int, int, "str | None", Path], tuple[list[SourceEpisode], int, int]]


def source_episodes(
    backend: str,
    demonstrator: Demonstrator,
    env: Env,
    num_demos: int,
    seed: int,
    from_file: str | None,
    work_dir: Path,
) -> tuple[list[SourceEpisode], int, int]:
    """Up to ``num_demos`` source demos on ``env`` of back end ``backend`` (its name) from
    that back end's ``demonstrator``, drawn from reset seeds seed, seed + 1, ... (or
    ``from_file``'s: a robomimic ``.hdf5`` of this back end and task, e.g. one the export
    stage wrote, its states checked first by :func:`check_file_states`, or a file format of
    the back end's own), how many the demonstrator dropped as failures, and how many seeds
    it tried (0 for a file)."""
    if from_file is None or not robomimic_source.is_robomimic_file(from_file):
        return demonstrator(env, num_demos, seed, from_file, work_dir)
    demos = robomimic_source.read(from_file, backend, env.spec.name)[:num_demos]
    return [SourceEpisode(d.seed, d.initial_state, d.actions) for d in demos], 0, 0


def check_file_states(
    backend: str, from_file: str, num_demos: int, make_env: Callable[[], Env]
) -> None:
    """InputError naming the demo when one of the first ``num_demos`` demos of the robomimic
    file ``from_file`` has states of another width than those of an env of ``make_env`` on
    back end ``backend`` (its name), which is started for the check and closed."""
    env = make_env()
    try:
        width = env.get_state().shape[-1]
        for demo in robomimic_source.read(from_file, backend, env.spec.name)[:num_demos]:
            if demo.initial_state.shape[-1] != width:
                raise InputError(
                    f"{from_file}: data/{demo.name}/states has {demo.initial_state.shape[-1]} "
                    f"values per step, expected {width} (the {backend} {env.spec.name} state "
                    f"with {env.robot})"
                )
    finally:
        env.close()
