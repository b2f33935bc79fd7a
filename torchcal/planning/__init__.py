"""Measurement planning: optimal pose selection (design) and pose ordering (order)."""
