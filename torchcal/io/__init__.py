"""Files: measurement CSV, MODEL.json (every fitted model, per zone included), partition and sweep files,
atomic writes. Every reader raises InputError naming the file and place; every writer is
atomic and refuses to replace a file without ``force``.

MODEL.json of a fit (of ``calibrate`` too) is read and written by `torchcal.io.modelfile.load` / ``to_dict``
(reached through the module: the names are too generic for the package).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.io.files": ["atomic_write", "check_output", "dumps_json", "read_json", "write_json"],
    "torchcal.io.mdh_table": ["mdh_table_csv"],
    "torchcal.io.export": ["Export"],
    "torchcal.io.measurement_csv": ["ANGLE_UNITS", "LENGTH_UNITS", "JointLimitWarning", "as_measurements",
                                    "format_measurements", "read_measurements", "write_measurements"],
    "torchcal.io.modelfile": ["file_sha256", "load_covariance"],
    "torchcal.io.plan_csv": ["plan_csv"],
    "torchcal.io.partition_file": ["load_partition", "partition_from_dict", "partition_from_json",
                                   "partition_record", "partition_to_dict", "partition_to_json", "save_partition"],
    "torchcal.io.sweep_blocks": ["BlockFolder"],
    "torchcal.io.targets_csv": ["compensation_csv", "read_targets"],
    "torchcal.io.truth_file": ["truth_to_dict"],
    "torchcal.io.sweep_csv": ["read_sweep", "sweep_columns", "sweep_csv_rows", "sweep_csv_text", "sweep_head",
                              "sweep_record", "write_sweep"],
})
