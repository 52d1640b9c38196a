"""The default pipeline's headline numbers as one flat JSON object (summary.json in the
report's folder) for ``dvc exp show`` and ``dvc metrics diff``: the numbers the report's
tables lead with, under short keys, as the report shows them."""

from __future__ import annotations

from mimicgen_pipe.metrics import Metrics
from mimicgen_pipe.params import Params
from mimicgen_pipe.report.fmt import fmt
from mimicgen_pipe.report.inputs import MetricsSet, coverage, evaluation, policy_data

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
