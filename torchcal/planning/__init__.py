"""Measurement planning: optimal pose selection (design) and pose ordering (order)."""

from torchcal.planning.design import CRITERIA, Plan, criterion, observability, select
from torchcal.planning.order import order_poses, path_length

__all__ = ["CRITERIA", "Plan", "criterion", "observability", "select", "order_poses", "path_length"]
