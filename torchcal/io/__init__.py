"""Files: measurement CSV, MODEL.json (fit and interval models), partition and sweep files,
atomic writes. Every reader raises InputError naming the file and place; every writer is
atomic and refuses to replace a file without ``force``.

MODEL.json of a fit is read and written by `torchcal.io.modelfile.load` / ``to_dict``
(reached through the module: the names are too generic for the package).
"""

from torchcal.io.files import atomic_write, check_output, dumps_json, read_json, write_json
from torchcal.io.interval_model import INTERVAL_MODEL_FORMAT, interval_model_from_dict, interval_model_to_dict
from torchcal.io.measurement_csv import (ANGLE_UNITS, LENGTH_UNITS, JointLimitWarning, format_measurements,
                                         read_measurements, write_measurements)
from torchcal.io.modelfile import file_sha256, load_covariance
from torchcal.io.partition_file import (load_partition, partition_from_dict, partition_from_json, partition_to_dict,
                                        partition_to_json, save_partition)
from torchcal.io.sweep_blocks import BlockFolder
from torchcal.io.sweep_csv import read_sweep, sweep_columns, sweep_csv_text, write_sweep

__all__ = ["atomic_write", "check_output", "dumps_json", "read_json", "write_json", "INTERVAL_MODEL_FORMAT",
           "interval_model_from_dict", "interval_model_to_dict", "ANGLE_UNITS", "LENGTH_UNITS", "JointLimitWarning",
           "format_measurements", "read_measurements", "write_measurements", "file_sha256", "load_covariance",
           "load_partition", "partition_from_dict", "partition_from_json", "partition_to_dict", "partition_to_json",
           "save_partition", "BlockFolder", "read_sweep", "sweep_columns", "sweep_csv_text", "write_sweep"]
