"""Measurement planning: optimal pose selection (design) and pose ordering (order).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.planning.design": ["CRITERIA", "Plan", "criterion", "observability", "select"],
    "torchcal.planning.order": ["order_poses", "path_length"],
})
