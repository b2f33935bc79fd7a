"""The sweep CSV written block by block: a folder of finished blocks next to the output.

A sweep of N points in blocks (torchcal.reliability.sweep_blocks.DEFAULT_BLOCK points each) that
writes ``OUT`` keeps, until it is complete, a folder ``OUT.blocks/`` holding

- ``manifest.json``: what the sweep computes (robot, clearance states, N, M, D, seed,
  block size), written first;
- ``block-000007.npz``: the summary statistics of block 7, then
- ``block-000007.csv``: its CSV rows (no header). Each file is written atomically (a
  temporary file in the folder, then a rename), and the rows file is written last: a
  block is complete exactly when its rows file exists, so a killed run leaves only
  whole blocks behind, and a rerun computes only the others.

When every block is there, the header and the blocks' rows are copied in order into
``OUT`` (again a temporary file and a rename: the same bytes as
`torchcal.io.sweep_csv.write_sweep` of the whole sweep computed at once), and the folder is
removed. Only the process that runs the sweep writes here (workers send their blocks to it).
"""

from __future__ import annotations

import io as _io
import json
import shutil
from pathlib import Path

import numpy as np

from torchcal.errors import InputError, OutputExistsError
from torchcal.io.files import atomic_open, atomic_write, dumps_json

__all__ = ["BlockFolder"]

MANIFEST = "manifest.json"


def _differs(key: str, there, here) -> str:
    if key.endswith("_sha256"):  # digests say only that something differs
        return f"{key[:-len('_sha256')].replace('_', ' ')} differ"
    return f"{key} {there!r} there, {here!r} here"


class BlockFolder:
    """The folder ``OUT.blocks`` of finished blocks of the sweep written to `out`."""

    def __init__(self, out):
        self.out = Path(out)
        self.path = self.out.with_name(self.out.name + ".blocks")

    def _rows(self, index: int) -> Path:
        return self.path / f"block-{index:06d}.csv"

    def _stats(self, index: int) -> Path:
        return self.path / f"block-{index:06d}.npz"

    def open(self, manifest: dict, *, force: bool = False) -> set[int]:
        """Create the folder, or take up the one a run with the same `manifest` left.

        Returns the indices of the complete blocks already there. A folder of a sweep
        with another manifest: InputError naming what differs, unless `force` (then it is
        emptied and the sweep starts over).
        """
        manifest = json.loads(dumps_json(manifest))  # as it reads back from the file
        if self.path.exists() and not self.path.is_dir():
            raise InputError(f"{self.path}: exists and is not a folder of sweep blocks; remove it")
        if self.path.is_dir() and any(self.path.iterdir()):
            old = self._read_manifest()
            if old != manifest:
                if not force:
                    diff = "; ".join(_differs(k, old.get(k), manifest.get(k))
                                     for k in sorted(set(old) | set(manifest)) if old.get(k) != manifest.get(k))
                    raise OutputExistsError(f"{self.path}: holds a partial sweep with other arguments ({diff}); "
                                     "rerun with the same arguments to finish it")
                shutil.rmtree(self.path)
        if not self.path.is_dir():
            self.path.mkdir()
        if not (self.path / MANIFEST).exists():
            atomic_write(self.path / MANIFEST, dumps_json(manifest))
        for tmp in self.path.glob(".*.tmp"):  # a killed run's unfinished writes
            tmp.unlink()
        done = set()
        for f in self.path.glob("block-*.csv"):
            done.add(int(f.stem.split("-")[1]))
        return done

    def _read_manifest(self) -> dict:
        try:
            return json.loads((self.path / MANIFEST).read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{self.path}: not a folder of sweep blocks (no readable {MANIFEST}: {exc}); "
                             "remove it") from None

    def write(self, index: int, rows: str, stats: dict) -> None:
        """Write block `index`: its statistics (arrays), then its rows (the commit)."""
        target = self._rows(index)
        if target.exists():
            raise RuntimeError(f"{target}: block {index} written twice")
        buf = _io.BytesIO()
        np.savez_compressed(buf, **stats)
        atomic_write(self._stats(index), buf.getvalue(), force=True)
        atomic_write(target, rows)

    def stats(self, index: int) -> dict:
        """The statistics arrays of a complete block."""
        with np.load(self._stats(index)) as z:
            return {k: z[k] for k in z.files}

    def assemble(self, header: str, n_blocks: int) -> Path:
        """Copy the header and blocks 0..n_blocks-1 into the output (atomically); remove the folder."""
        with atomic_open(self.out, "wb", force=True) as fh:
            fh.write(header.encode())
            for b in range(n_blocks):
                with open(self._rows(b), "rb") as part:
                    shutil.copyfileobj(part, fh, 1 << 20)
        shutil.rmtree(self.path)
        return self.out
