"""params.yaml validation and the Zarr store (no simulator)."""

import numpy as np
import pytest

from mimicgen_pipe import poses
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.params import load_params
from mimicgen_pipe.store import read_store, write_store


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
        ("generate: {selection: nn}", "generate.selection: expected one of"),
        ("generate: {per_subtask: 1}", "generate.per_subtask: expected true/false"),
        ("generate: {nosie: 0.1}", "generate.nosie: unknown key"),
        ("generate: {action_noise: -0.1}", "generate.action_noise: expected a value in"),
        ("source: [1, 2]", "source: expected a mapping"),
    ],
)
def test_bad_params_name_the_key(tmp_path, text, needle):
    with pytest.raises(InputError, match=needle.replace("(", r"\(")):
        load_params(write(tmp_path, text))


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
