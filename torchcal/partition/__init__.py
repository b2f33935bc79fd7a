"""Workspace partition: fuzzy c-means clustering and the zones it defines.
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.partition.fcm": ["FCMResult", "memberships", "objective"],
    "torchcal.partition.validity": ["choose_c", "partition_coefficient", "partition_entropy", "xie_beni"],
    "torchcal.partition.zones": ["Partition", "ZoneSizeWarning", "partition_workspace"],
})
