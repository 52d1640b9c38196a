"""Each pipeline's headline numbers as one flat JSON object (summary.json in its report's
folder) for ``dvc exp show`` and ``dvc metrics diff``: the numbers the report's
tables lead with, under short keys, as the report shows them."""

from __future__ import annotations

from mimicgen_pipe.metrics import Metrics
from mimicgen_pipe.params import Params
from mimicgen_pipe.report.fmt import fmt
from mimicgen_pipe.report.inputs import MetricsSet, coverage, evaluation, policy_data
from mimicgen_pipe.report.suite import dgr_run
from mimicgen_pipe.report.transfer import transfer_cell
from mimicgen_pipe.report.transit import transit_cells, transit_run, wall_evaluation

SUMMARY = "summary.json"


def _shown(m: Metrics | None, key: str) -> float | None:
    """``m``'s value of ``key`` rounded as a report table shows it; None when absent."""
    value = m.values.get(key) if m else None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(fmt(value))


def headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """Per reset variant v of generate.variants (four keys each, twelve for D0, D1, D2):

    - ``dgr_<v>``: the DGR [%] of the generate run policies train on (the DGR table's);
    - ``sr_source_on_<v>``, ``sr_<v>_on_<v>``: the success rate [%] in v of the policy
      trained on the source demos / on v's generated demos, max over its checkpoints, mean
      over training seeds (the policy table's "SR max");
    - ``coverage_<v>``: the joint support coverage [%] of v's generated scenes (the coverage
      table's "joint").

    A number whose metrics are not in ``ms`` is left out."""
    task, backend = params.task, params.backend
    numbers: dict[str, float | None] = {}
    for v in params.generate.variants:
        numbers[f"dgr_{v}"] = _shown(policy_data(ms, params, task, backend, v), "dgr")
        for data in ("source", v):
            ev = evaluation(ms, params, task, backend, data, v)
            numbers[f"sr_{data}_on_{v}"] = _shown(ev, "success_rate_max")
        numbers[f"coverage_{v}"] = _shown(coverage(ms, params, v), "support_coverage_joint")
    return {k: x for k, x in sorted(numbers.items()) if x is not None}


def suite_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The task suite's headline numbers, per task t of suite.tasks and reset variant v of
    suite.variants: ``dgr_<t>_<v>`` (the DGR table's fixed attempts) and
    ``sr_<t>_<data>_on_<v>`` for the source and generated policies (SR max, mean over
    seeds). A number whose metrics are not in ``ms`` is left out."""
    u = params.suite
    numbers: dict[str, float | None] = {}
    for task in u.tasks:
        for v in u.variants:
            numbers[f"dgr_{task}_{v}"] = _shown(dgr_run(ms, params, task, v), "dgr")
            for data in ("source", v):
                ev = evaluation(ms, params, task, u.backend, data, v)
                numbers[f"sr_{task}_{data}_on_{v}"] = _shown(ev, "success_rate_max")
    return {k: x for k, x in sorted(numbers.items()) if x is not None}


def transit_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The transit pipeline's headline numbers: ``dgr_<task>_<variant>_<transit>`` per cell
    and transit (linear, planned), and ``sr_wall_<transit>`` (SR max of the wall variant's
    policies). A number whose metrics are not in ``ms`` is left out."""
    numbers: dict[str, float | None] = {}
    for task, variant in transit_cells(params):
        for transit in ("linear", "planned"):
            run = transit_run(ms, task, variant, planned=transit == "planned")
            numbers[f"dgr_{task}_{variant}_{transit}"] = _shown(run, "dgr")
    for transit in ("linear", "planned"):
        numbers[f"sr_wall_{transit}"] = _shown(wall_evaluation(ms, transit), "success_rate_max")
    return {k: x for k, x in sorted(numbers.items()) if x is not None}


def transfer_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The robot-transfer pipeline's headline numbers: ``dgr_<task>_<variant>_<robot>`` for
    every cell of transfer.tasks x transfer.variants x transfer.robots and of the default
    pipeline's task x generate.variants x transfer.maniskill_robots; ``sr_<task>_D0_on_D0``
    for each task of transfer.policy_tasks (SR max, mean over seeds). A number whose metrics
    are not in ``ms`` is left out."""
    t = params.transfer
    cells = [(t.backend, task, v, r) for task in t.tasks for v in t.variants for r in t.robots]
    cells += [
        (params.backend, params.task, v, r)
        for v in params.generate.variants
        for r in t.maniskill_robots
    ]
    numbers = {
        f"dgr_{task}_{v}_{r}": _shown(transfer_cell(ms, task, backend, v, r), "dgr")
        for backend, task, v, r in cells
    }
    for task in t.policy_tasks:
        ev = evaluation(ms, params, task, t.backend, "D0", "D0")
        numbers[f"sr_{task}_D0_on_D0"] = _shown(ev, "success_rate_max")
    return {k: x for k, x in sorted(numbers.items()) if x is not None}
