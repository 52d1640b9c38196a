"""params.yaml validation and the Zarr store (no simulator)."""

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import read_store, write_store


def write(tmp_path, text):
    p = tmp_path / "params.yaml"
    p.write_text(text)
    return p


def test_defaults_are_the_papers():
    from pathlib import Path

    p = load_params(Path(__file__).parents[1] / "params.yaml")
    g = p.generate
    assert (g.action_noise, g.n_interp, g.n_fixed, g.selection, g.per_subtask) == (
        0.05,
        5,
        0,
        "random",
        False,
    )
    assert p.source.num_demos == 10


@pytest.mark.parametrize(
    "text,needle",
    [
        ("generate: {action_noise: abc}", "generate.action_noise: expected a number"),
        ("generate: {n_interp: 2.5}", "generate.n_interp: expected an integer"),
        (
            "generate: {selection: nn}",
            "generate.selection: expected one of 'nearest_neighbor', "
            "'nearest_neighbor_robot_distance', 'random', got 'nn'",
        ),
        (
            "backend: bullet\nsource: {}",
            "backend: expected one of 'maniskill', 'pybullet', got 'bullet'",
        ),
        ("suite: {backend: mujoco}", "suite.backend: expected one of 'maniskill', 'pybullet'"),
        ("generate: {executor: dask}", "generate.executor: expected one of 'local', 'ray'"),
        (
            "export: {formats: [robomimic, hdf6]}",
            "export.formats: expected entries among 'lerobot', 'maniskill', 'robomimic', "
            "got 'hdf6'",
        ),
        ("maniskill: {fast_step: true}", "maniskill.fast_step: unknown key (known: lean_step"),
        ("generate: {per_subtask: 1}", "generate.per_subtask: expected true/false"),
        ("generate: {nosie: 0.1}", "generate.nosie: unknown key"),
        ("generate: {action_noise: -0.1}", "generate.action_noise: expected a value in"),
        ("source: [1, 2]", "source: expected a mapping"),
        (
            "suite: {scaling: {num_demos: [1000, 200]}}",
            "suite.scaling.num_demos: expected a non-empty list in increasing order",
        ),
        ("suite: {scaling: {num_demos: [0, 5]}}", "suite.scaling.num_demos: expected each entry"),
        ("suite: {scaling: {num_demos: 200}}", "suite.scaling.num_demos: expected a list of"),
    ],
)
def test_bad_params_name_the_key(tmp_path, text, needle):
    with pytest.raises(InputError, match=needle.replace("(", r"\(")):
        load_params(write(tmp_path, text))


@pytest.mark.parametrize(
    "scaling,needle",
    [
        ("{task: stack_pyramid}", "suite.scaling.task: 'stack_pyramid' is not in suite.tasks"),
        (
            "{task: place_sphere, demos: 500, num_demos: [200, 1000]}",
            "suite.scaling.num_demos: 1000 is more than the 500 demos of suite.scaling.demos",
        ),
        ("{task: place_sphere, variant: D7}", "suite.scaling.variant: 'D7' is not a reset"),
    ],
)
def test_the_scaling_task_is_a_suite_task_with_its_demos(tmp_path, scaling, needle):
    from mimicgen_pipe.stages.check import check_suite

    suite = "suite: {tasks: [place_sphere], scaling: "
    with pytest.raises(InputError, match=needle):
        check_suite(load_params(write(tmp_path, suite + scaling + "}")), "params.yaml")
    ok = suite + "{task: place_sphere, variant: D1}}"
    check_suite(load_params(write(tmp_path, ok)), "params.yaml")


def test_a_transfer_policy_task_is_a_transfer_task(tmp_path):
    """transfer.policy_tasks' policy data comes from transfer's own source demos."""
    from mimicgen_pipe.stages.check import check_transfer

    text = "transfer: {tasks: [stack, stack_three], policy_tasks: [%s]}"
    with pytest.raises(InputError, match="transfer.policy_tasks: 'square_peg' is not in "
                       "transfer.tasks"):  # fmt: skip
        check_transfer(load_params(write(tmp_path, text % "square_peg")), "params.yaml")
    check_transfer(load_params(write(tmp_path, text % "stack_three")), "params.yaml")
    with pytest.raises(InputError, match="transfer.policy_seeds: expected a value in"):
        load_params(write(tmp_path, "transfer: {policy_seeds: 0}"))


# every seed: generation and evaluation derive reset seeds from theirs with SeedSequence,
# pose_noise and train seed numpy / torch generators: none takes a negative seed
@pytest.mark.parametrize(
    "text,needle",
    [
        ("generate: {seed: -1}", "generate.seed: expected a value in [0, 2147483647], got -1"),
        ("evaluate: {seed: -3}", "evaluate.seed: expected a value in [0, 2147483647], got -3"),
        ("pose_noise: {seed: -1}", "pose_noise.seed: expected a value in [0, 2147483647]"),
        ("generate: {seed: 4294967296}", "generate.seed: expected a value in [0, 2147483647]"),
        ("source: {seed: -1}", "source.seed: expected a value in [0, 536870912], got -1"),
        (
            "train: {cpu: {seeds: [0, -1]}}",
            "train.cpu.seeds: expected each entry a value in [0, 2147483647], got -1",
        ),
        ("train: {paper: {seeds: [1, 1]}}", "train.paper.seeds: expected distinct entries"),
        ("train: {cpu: {seeds: []}}", "train.cpu.seeds: expected at least one entry"),
        ("generate: {seed: true}", "generate.seed: expected an integer, got True"),
        ("source: {from_file: ''}", "source.from_file: expected a file path or null, got ''"),
        # keys YAML reads as numbers or booleans, beside text keys
        ("generate: {yes: 1, nosie: 2, 3: 4}", "generate.3: unknown key"),
    ],
)
def test_out_of_range_seeds_and_odd_keys_name_the_key(tmp_path, text, needle):
    with pytest.raises(InputError) as exc:
        load_params(write(tmp_path, text))
    assert str(exc.value).startswith(f"{tmp_path / 'params.yaml'}: ")
    assert needle in str(exc.value)
    assert "\n" not in str(exc.value)


def test_the_largest_seeds_pass_and_every_derived_seed_stays_valid(tmp_path):
    from mimicgen_pipe.learn.evaluation import evaluation_seed
    from mimicgen_pipe.run.runner import attempt_seed

    top = 2**31 - 1
    p = load_params(
        write(
            tmp_path,
            f"generate: {{seed: {top}}}\nevaluate: {{seed: {top}}}\npose_noise: {{seed: {top}}}\n"
            f"train: {{cpu: {{seeds: [0, {top}]}}}}\nsource: {{seed: {2**29}}}\n",
        )
    )
    assert 0 <= attempt_seed(p.generate.seed, "D1", 10**6) < 2**30
    assert 2**30 <= evaluation_seed(p.evaluate.seed, "D1", 10**5) < 2**31
    np.random.default_rng(p.pose_noise.seed)
    np.random.default_rng(p.train.cpu.seeds[-1])


@pytest.mark.parametrize(
    "content,needle",
    [
        (b"", "params.yaml: empty"),
        (b"[task, source]\n", "params.yaml: top level: expected a mapping, got ['task', 'source']"),
        (b"task: stack_cube\nsource: {seed: 1\n", "params.yaml: not valid YAML: line 3, column 1"),
        (b"task: st\xe4ck\n", "params.yaml: not UTF-8 text (byte 0xe4 at offset 8)"),
        (b"source:\n  seed: 1\n  num_demos: 2\n  seed: 3\n", "key 'seed' appears twice"),
        (
            b"generate: {seed: 1}\nsource: {seed: 0}\ngenerate: {seed: 2}\n",
            "params.yaml: not valid YAML: key 'generate' appears twice in one mapping "
            "(lines 1 and 3); give each key once",
        ),
    ],
)
def test_odd_params_files_are_one_line_naming_the_file(tmp_path, content, needle):
    path = tmp_path / "params.yaml"
    path.write_bytes(content)
    with pytest.raises(InputError) as exc:
        load_params(path)
    assert needle in str(exc.value) and "\n" not in str(exc.value)
    assert str(exc.value).startswith(str(path))


def alias_bomb(levels: int) -> str:
    """A params file of ~0.5 kB whose nested aliases, under a known key, expand to 10**levels
    values."""
    anchors = ["  - &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    anchors += [f"  - &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "task: stack_cube\ngenerate:\n  num_demos:\n" + "\n".join(anchors) + "\n"


def test_yaml_aliases_that_expand_a_file_past_its_limit_are_one_error_at_once(tmp_path):
    import time

    path = tmp_path / "params.yaml"
    path.write_text(alias_bomb(10))
    assert len(path.read_bytes()) < 1024
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"params.yaml: not valid YAML: its aliases expand it "
                       r"to 12345679017 nodes, more than the 100000"):  # fmt: skip
        load_params(path)
    assert time.monotonic() - t0 < 5
    # under the limit, a wrong value's message shows a few entries of it, not all of them
    path.write_text(alias_bomb(4))
    with pytest.raises(InputError, match=r"generate.num_demos: expected an int") as err:
        load_params(path)
    assert len(str(err.value)) < 300


def test_store_round_trip_and_atomic_replace(tmp_path):
    rng = np.random.default_rng(0)
    eps = []
    for t in (3, 5):
        q = rng.standard_normal((t, 4))
        eps.append(
            {
                "actions": rng.standard_normal((t, 7)).astype(np.float32),
                "eef_pose": poses.pose_from_pq(rng.standard_normal((t, 3)), q),
            }
        )
    path = tmp_path / "s.zarr"
    write_store(path, "generated", eps, {"seed": np.array([1, 2])}, {"task": "t"})
    s = read_store(path, required=["actions"])
    assert s.episode_ends.tolist() == [3, 8]
    np.testing.assert_array_equal(s.episode(1)["actions"], eps[1]["actions"])
    np.testing.assert_allclose(s.poses("eef_pose")[3:], eps[1]["eef_pose"], atol=1e-12)
    assert s.attrs["task"] == "t"
    # a failing write leaves the old store in place and no temporary directory behind
    with pytest.raises(KeyError):
        write_store(
            path, "generated", [{"actions": np.zeros((2, 7))}, {"other": np.zeros(2)}], {}, {}
        )
    assert read_store(path).n_episodes == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.zarr"]
    with pytest.raises(InputError, match="missing data keys"):
        read_store(path, required=["target_pose"])
