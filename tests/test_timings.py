"""Wall-clock times stay out of the metrics files a pipeline tracks: one rule says which
fields are times, metrics files refuse them, and a stage's times go to a timings file whose
path mirrors its metrics file's (no simulator)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.data.metrics import (
    IDENTITY_FIELDS,
    cpu_type,
    generation_metrics,
    is_timing,
    metrics_identity,
    split_timings,
    timings_file,
    write_metrics,
    write_timings,
)

# every wall-clock field a stage writes, by stage (grep of mimicgen_pipe/, scripts/)
TIMING_KEYS = {
    "generate": ["seconds_per_attempt_mean", "seconds_per_attempt_median", "wall_seconds"],
    "train": ["wall_seconds", "seconds_per_1000_steps", "epoch_seconds"],  # and robomimic's
    "evaluate": ["wall_seconds", "seconds_per_episode"],  # evaluate_external too
    "export": ["robomimic_seconds", "lerobot_seconds", "maniskill_seconds"],
    "render": ["ms_per_frame"],
    "observe": ["seconds", "ms_per_frame_agentview", "ms_per_frame_eye_in_hand"],
}
# results the stages write, the ones whose names come nearest the timing rule among them
RESULT_KEYS = [
    "dgr", "attempts", "successes", "steps", "frames", "episodes", "run_id", "data_run_id",
    "ik_failures", "failures_retreat", "planner_failures_grasp_cubeA", "support_coverage_cube",
    "robomimic_image_bytes", "lerobot_image_bytes", "maniskill_replay_success",
    "image_mb_per_1000_demos", "gradient_steps", "final_loss", "seed0_best_epoch",
    "seed0_success_rate_max", "success_rate_last_std", "seeds", "checkpoints", "horizon",
    "every_epochs", "workers", "executor", "torch_threads", "trainings_side_by_side",
    "trainings_stacked", "epochs", "checkpoint_epochs", "mean_length", "demos", "bins",
    "outside_bounds", "dropped_replay", "epoch_unit", "policy_sha256", "profile",
]  # fmt: skip


@pytest.mark.parametrize("key", [k for keys in TIMING_KEYS.values() for k in keys])
def test_every_timing_field_a_stage_writes_is_a_timing(key: str) -> None:
    assert is_timing(key)


@pytest.mark.parametrize("key", RESULT_KEYS)
def test_no_result_field_is_a_timing(key: str) -> None:
    assert not is_timing(key)


def test_generation_metrics_split_into_results_and_its_times() -> None:
    values = generation_metrics(
        np.array([True, False]), np.array([-1, 0]), np.array([0.5, 1.5]), ["grasp"]
    )
    results, timings = split_timings(values | {"wall_seconds": 2.0, "steps": 90})
    assert timings == {
        "seconds_per_attempt_mean": 1.0,
        "seconds_per_attempt_median": 1.0,
        "wall_seconds": 2.0,
    }
    assert results["dgr"] == 50.0 and results["steps"] == 90 and "failures_grasp" in results


@pytest.mark.parametrize(
    ("metrics", "timings"),
    [
        ("metrics/generate_x.json", "timings/generate_x.json"),
        ("suite/metrics/generate/x.json", "suite/timings/generate/x.json"),
        ("quickstart/metrics/render_x.json", "quickstart/timings/render_x.json"),
        ("/a/metrics/b/metrics/x.json", "/a/metrics/b/timings/x.json"),  # the last one
        ("scratch/metrics.json", "scratch/metrics.timings.json"),  # a file, not a folder
        ("g.json", "g.timings.json"),
        ("/tmp/run/m.json", "/tmp/run/m.timings.json"),
    ],
)
def test_timings_file_mirrors_the_metrics_path(metrics: str, timings: str) -> None:
    assert timings_file(metrics) == Path(timings)


def test_write_metrics_refuses_a_timing_and_writes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "metrics" / "m.json"
    with pytest.raises(ValueError, match="wall_seconds"):
        write_metrics(path, {"dgr": 50.0, "wall_seconds": 3.0})
    assert not path.exists()


def test_write_timings_writes_identity_and_times_beside_the_metrics(tmp_path: Path) -> None:
    identity = metrics_identity("render", "stack_cube", "maniskill", "panda", variant="D0")
    path = write_timings(tmp_path / "metrics" / "r.json", identity, {"ms_per_frame": 12.5})
    assert path == tmp_path / "timings" / "r.json"
    assert json.loads(path.read_text()) == identity | {"ms_per_frame": 12.5, "cpu": cpu_type()}
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # no temporary left
    with pytest.raises(ValueError, match="frames"):
        write_timings(tmp_path / "metrics" / "r.json", identity, {"frames": 3})


def test_write_timings_leaves_what_is_no_json_object_alone(tmp_path: Path, capsys) -> None:
    """The file is informational and written after the stage's outputs are committed: what
    lies in its place (not a JSON object) is kept, with one warning, and the stage goes on."""
    (tmp_path / "timings").mkdir()
    theirs = tmp_path / "timings" / "r.json"
    theirs.write_text("not ours\n")
    identity = metrics_identity("render", "stack_cube", "maniskill", "panda", variant="D0")
    assert write_timings(tmp_path / "metrics" / "r.json", identity, {"ms_per_frame": 1.0}) is None
    assert theirs.read_text() == "not ours\n"
    (line,) = capsys.readouterr().err.splitlines()
    assert str(theirs) in line and "not JSON" in line


def test_committed_metrics_hold_no_time_and_timings_only_times() -> None:
    """Every stage's metrics file committed in this repository holds no wall-clock field,
    and every committed timings file holds its identity fields (with generate's run id) and
    times of TIMING_KEYS only: a result field named like a time would leave its metrics
    file, and a time missed by the rule would stay in it."""
    repo = Path(__file__).resolve().parents[1]
    known = {k for keys in TIMING_KEYS.values() for k in keys}
    fields: set[str] = set()
    for path in [*repo.glob("metrics/**/*.json"), *repo.glob("*/metrics/**/*.json")]:
        values = json.loads(path.read_text())
        if isinstance(values, dict) and "stage" in values:  # benchmarks' figures are not
            fields |= set(values)
    assert len(fields) > 100
    assert not [k for k in fields if is_timing(k) or k in known]
    timed: set[str] = set()
    for path in [*repo.glob("timings/**/*.json"), *repo.glob("*/timings/**/*.json")]:
        timed |= set(json.loads(path.read_text()))
    assert timed - known <= {*IDENTITY_FIELDS, "run_id", "cpu"}  # cpu: since it is recorded
    assert {*IDENTITY_FIELDS, "run_id"} <= timed


def test_the_cpu_type_names_vendor_model_and_the_kernel_flags() -> None:
    """Where a stage ran, as /proc/cpuinfo says: the first processor's vendor, model and the
    flags that pick numpy's and torch's kernels (AVX-512 moves last bits)."""
    zen4 = (
        "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\n"
        "model name\t: AMD EPYC 9R14\nflags\t\t: fpu sse2 avx2 fma avx512f avx512_vnni\n\n"
        "processor\t: 1\nvendor_id\t: GenuineIntel\n"
    )
    assert cpu_type(zen4) == {
        "vendor": "AuthenticAMD", "model_name": "AMD EPYC 9R14", "family": 25, "model": 17,
        "flags": ["avx2", "fma", "avx512f", "avx512_vnni"],
    }  # fmt: skip
    assert cpu_type("") == {
        "vendor": None,
        "model_name": None,
        "family": None,
        "model": None,
        "flags": [],
    }
