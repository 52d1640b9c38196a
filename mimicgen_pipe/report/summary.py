"""Each pipeline's headline numbers as one flat JSON object (summary.json in its report's
folder) for ``dvc exp show`` and ``dvc metrics diff``: the numbers the report's
tables lead with, under short keys, as the report shows them; each DGR and success rate
``<key>`` with the bounds of its 95% interval as ``<key>_lo`` and ``<key>_hi`` where its
counts are known (mimicgen_pipe.report.fmt.wilson_interval)."""

from __future__ import annotations

from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.fmt import CI_BOUNDS, dgr_counts, fmt, sr_counts, wilson_interval
from mimicgen_pipe.report.images import DATA, VARIANT
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


def _dgr(m: Metrics | None) -> dict[str, float | None]:
    """A generate run's DGR as shown, and its interval's bounds: {"": dgr, "_lo", "_hi"}."""
    return _rate(m, "dgr", dgr_counts(m.values) if m else None)


def _sr(m: Metrics | None) -> dict[str, float | None]:
    """An evaluation's success rate max as shown, and its interval's bounds (pooled
    episodes, mimicgen_pipe.report.fmt.sr_counts)."""
    return _rate(m, "success_rate_max", sr_counts(m.values) if m else None)


def _rate(m: Metrics | None, key: str, counts: tuple[int, int] | None) -> dict[str, float | None]:
    shown = _shown(m, key)
    ci = wilson_interval(*counts) if counts and shown is not None else None
    if ci is None:
        return {"": shown}
    return {"": shown} | {s: float(fmt(b)) for s, b in zip(CI_BOUNDS, ci, strict=True)}


def _flat(named: dict[str, dict[str, float | None]]) -> dict[str, float]:
    """name -> {suffix: number} as sorted flat keys, those without a number left out."""
    flat = {name + s: x for name, by in named.items() for s, x in by.items()}
    return {k: x for k, x in sorted(flat.items()) if x is not None}


def headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """Per reset variant v of generate.variants (four keys each, twelve for D0, D1, D2):

    - ``dgr_<v>``: the DGR [%] of the generate run policies train on (the DGR table's);
    - ``sr_source_on_<v>``, ``sr_<v>_on_<v>``: the success rate [%] in v of the policy
      trained on the source demos / on v's generated demos, max over its checkpoints, mean
      over training seeds (the policy table's "SR max");
    - ``coverage_<v>``: the joint support coverage [%] of v's generated scenes (the coverage
      table's "joint").

    DGRs and success rates with their interval's bounds (``_lo``, ``_hi``). A number whose
    metrics are not in ``ms`` is left out."""
    task, backend = params.task, params.backend
    numbers: dict[str, dict[str, float | None]] = {}
    for v in params.generate.variants:
        numbers[f"dgr_{v}"] = _dgr(policy_data(ms, params, task, backend, v))
        for data in ("source", v):
            numbers[f"sr_{data}_on_{v}"] = _sr(evaluation(ms, params, task, backend, data, v))
        cov = _shown(coverage(ms, params, v), "support_coverage_joint")
        numbers[f"coverage_{v}"] = {"": cov}
    return _flat(numbers)


def suite_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The task suite's headline numbers, per task t of suite.tasks and reset variant v of
    suite.variants: ``dgr_<t>_<v>`` (the DGR table's fixed attempts) and
    ``sr_<t>_<data>_on_<v>`` for the source and generated policies (SR max, mean over
    seeds), each with its interval's bounds. A number whose metrics are not in ``ms`` is left
    out."""
    u = params.suite
    numbers: dict[str, dict[str, float | None]] = {}
    for task in u.tasks:
        for v in u.variants:
            numbers[f"dgr_{task}_{v}"] = _dgr(dgr_run(ms, params, task, v))
            for data in ("source", v):
                ev = evaluation(ms, params, task, u.backend, data, v)
                numbers[f"sr_{task}_{data}_on_{v}"] = _sr(ev)
    return _flat(numbers)


def transit_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The transit pipeline's headline numbers: ``dgr_<task>_<variant>_<transit>`` per cell
    and transit (linear, planned), and ``sr_wall_<transit>`` (SR max of the wall variant's
    policies), each with its interval's bounds. A number whose metrics are not in ``ms`` is
    left out."""
    numbers: dict[str, dict[str, float | None]] = {}
    for task, variant in transit_cells(params):
        for transit in ("linear", "planned"):
            run = transit_run(ms, task, variant, planned=transit == "planned")
            numbers[f"dgr_{task}_{variant}_{transit}"] = _dgr(run)
    for transit in ("linear", "planned"):
        numbers[f"sr_wall_{transit}"] = _sr(wall_evaluation(ms, transit))
    return _flat(numbers)


def images_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The image-agent pipeline's headline numbers: ``sr_source_on_D0`` and ``sr_D0_on_D0``,
    the image agents' success rate max on D0 (mean over seeds) trained on the source demos
    and on the generated D0 demos, each with its interval's bounds. A number whose metrics
    are not in ``ms`` is left out."""
    numbers = {
        f"sr_{data}_on_{VARIANT}": _sr(
            evaluation(ms, params, params.task, params.backend, data, VARIANT)
        )
        for data in DATA
    }
    return _flat(numbers)


def transfer_headline_numbers(params: Params, ms: MetricsSet) -> dict[str, float]:
    """The robot-transfer pipeline's headline numbers: ``dgr_<task>_<variant>_<robot>`` for
    every cell of transfer.tasks x transfer.variants x transfer.robots and of the default
    pipeline's task x generate.variants x transfer.maniskill_robots; ``sr_<task>_D0_on_D0``
    for each task of transfer.policy_tasks (SR max, mean over seeds); each with its
    interval's bounds. A number whose metrics are not in ``ms`` is left out."""
    t = params.transfer
    cells = [(t.backend, task, v, r) for task in t.tasks for v in t.variants for r in t.robots]
    cells += [
        (params.backend, params.task, v, r)
        for v in params.generate.variants
        for r in t.maniskill_robots
    ]
    numbers = {
        f"dgr_{task}_{v}_{r}": _dgr(transfer_cell(ms, task, backend, v, r))
        for backend, task, v, r in cells
    }
    for task in t.policy_tasks:
        ev = evaluation(ms, params, task, t.backend, "D0", "D0")
        numbers[f"sr_{task}_D0_on_D0"] = _sr(ev)
    return _flat(numbers)
