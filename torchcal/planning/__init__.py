"""Measurement planning: optimal pose selection (design), pose ordering (order) and the
whole plan of ``torchcal plan`` (plan).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.planning.design": ["CRITERIA", "Plan", "criterion", "observability", "select"],
    "torchcal.planning.order": ["order_poses", "path_length"],
    "torchcal.planning.plan": ["MeasurementPlan", "plan"],
})
