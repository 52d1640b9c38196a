"""generate's numeric options stand in for params keys and are held to the same ranges as
the params file's (mimicgen_pipe.data.params): one line naming the option, the value and the
range, exit 2, before any work (a real ``mimicgen-pipe generate``)."""

from __future__ import annotations

import pytest

from tests.test_cli_errors import run_bad


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--attempts", "1000000000000", "[1, 10000000] (the range of generate.max_attempts)"),
        ("--attempts", "0", "[1, 10000000] (the range of generate.max_attempts)"),
        ("--action-noise", "inf", "[0.0, 1.0] (the range of generate.action_noise)"),
        ("--action-noise", "nan", "[0.0, 1.0] (the range of generate.action_noise)"),
        ("--num-demos", "-1", "[0, 10000000] (the range of generate.num_demos)"),
        ("--max-attempts", "0", "[1, 10000000] (the range of generate.max_attempts)"),
    ],
)
def test_an_option_out_of_its_keys_range_is_one_error(tmp_path, option, value, expected):
    msg = run_bad(tmp_path, "generate", "--variant", "D0", option, value)
    shown = repr(float(value)) if option == "--action-noise" else value
    assert msg == (
        f"mimicgen-pipe generate: error: {option} {shown}: expected a value in {expected}, "
        f"got {shown}"
    )


def test_attempts_and_num_demos_together_is_one_error(tmp_path):
    msg = run_bad(tmp_path, "generate", "--variant", "D0", "--attempts", "5", "--num-demos", "5")
    assert msg == (
        "mimicgen-pipe generate: error: --attempts and --num-demos: one of them (fixed "
        "attempts or demos)"
    )


def test_num_demos_and_transit_stand_in_for_their_keys():
    from mimicgen_pipe.data.params import Params
    from mimicgen_pipe.stages.generate import with_generate_options

    g = with_generate_options(Params(), None, None, "planned", 7).generate
    assert (g.mode, g.num_demos, g.transit) == ("guarantee", 7, "planned")
    g = with_generate_options(Params(), 30, None).generate
    assert (g.mode, g.max_attempts, g.transit) == ("fixed_attempts", 30, "linear")
    g = with_generate_options(Params(), None, None, None, 5000, 15000).generate
    assert (g.mode, g.num_demos, g.max_attempts) == ("guarantee", 5000, 15000)


def test_attempts_and_max_attempts_together_is_one_error(tmp_path):
    msg = run_bad(tmp_path, "generate", "--variant", "D0", "--attempts", "5",
                  "--max-attempts", "50")  # fmt: skip
    assert msg == (
        "mimicgen-pipe generate: error: --attempts and --max-attempts: one of them "
        "(--attempts is the count)"
    )


def test_train_num_demos_is_held_to_its_keys_range(tmp_path):
    msg = run_bad(tmp_path, "train", "--data", "D0", "--num-demos", "0")
    assert msg == (
        "mimicgen-pipe train: error: --num-demos 0: expected a value in [1, 10000000] (the "
        "range of train.num_demos), got 0"
    )


def test_train_num_demos_is_one_count_or_one_per_data(tmp_path):
    import argparse

    from mimicgen_pipe.data.params import load_params
    from mimicgen_pipe.stages.train import policies

    (tmp_path / "params.yaml").write_text("task: stack_cube\ntrain: {num_demos: 300}\n")
    params = load_params(tmp_path / "params.yaml")

    def counts(data, num_demos):
        args = argparse.Namespace(data=data, num_demos=num_demos, store=["s"] * len(data),
                                  out=None, metrics=None, plot=None)  # fmt: skip
        return [p.num_demos for p in policies(args, params)]

    assert counts(["a", "b"], None) == [300, 300]  # train.num_demos
    assert counts(["a", "b"], [20]) == [20, 20]
    assert counts(["a", "b", "c"], [20, 50, 80]) == [20, 50, 80]
    msg = run_bad(tmp_path, "train", "--data", "D0", "D1", "--num-demos", "1", "2", "3")
    assert msg == (
        "mimicgen-pipe train: error: --num-demos: expected one count, or one per --data (2), got 3"
    )


def test_train_num_seeds_stands_in_for_the_profiles_seeds(tmp_path):
    import argparse

    from mimicgen_pipe.data.params import load_params
    from mimicgen_pipe.stages.train import with_seeds

    (tmp_path / "params.yaml").write_text("task: stack_cube\ntrain: {cpu: {seeds: [7]}}\n")
    params = load_params(tmp_path / "params.yaml")
    seeded = with_seeds(params, argparse.Namespace(num_seeds=3))
    assert seeded.train.cpu.seeds == [0, 1, 2] and params.train.cpu.seeds == [7]
    assert seeded.train.paper == params.train.paper  # only the active profile's
    assert with_seeds(params, argparse.Namespace(num_seeds=None)) == params
    msg = run_bad(tmp_path, "train", "--data", "D0", "--num-seeds", "0")
    assert msg == (
        "mimicgen-pipe train: error: --num-seeds 0: expected a value in [1, 100] (the range of "
        "suite.policy_seeds), got 0"
    )
