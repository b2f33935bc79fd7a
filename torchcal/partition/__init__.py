"""Workspace partition: fuzzy c-means clustering and the zones it defines."""

from torchcal.partition.fcm import (FCMResult, FuzzyCMeans, choose_c, fcm, memberships, objective,
                                    partition_coefficient, partition_entropy, xie_beni)
from torchcal.partition.zones import Partition, partition_workspace

__all__ = ["FCMResult", "FuzzyCMeans", "choose_c", "fcm", "memberships", "objective", "partition_coefficient",
           "partition_entropy", "xie_beni", "Partition", "partition_workspace"]
