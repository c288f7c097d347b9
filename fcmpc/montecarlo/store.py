"""Per-run results on disk as Parquet (pyarrow), one row per run, appended as runs finish.

A store is a folder of immutable part files (``part-<ns>-<pid>.parquet``), each written to a
temporary name and renamed, so an interrupted sweep leaves only whole files and the next call
resumes from them. Every row carries ``run_key``, a digest of everything the run depends on
(:func:`run_key`), so a second call skips the runs already stored, and two sweeps that share a
cell share its runs. Parts written by different sweeps may have different columns; reading
unifies them (missing columns are null).
"""
from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from fcmpc.montecarlo.runs import RunSpec

__all__ = ["RunStore", "run_key"]


def run_key(spec: RunSpec, scenario_repr: str) -> str:
    """Digest of what a run depends on: the scenario after its changes (``repr`` of the frozen
    dataclass, floats exactly), every registry value, the seed and the storm flag."""
    text = repr((scenario_repr, sorted(spec.values), spec.seed, spec.storm))
    return hashlib.sha256(text.encode()).hexdigest()[:20]


class RunStore:
    """The Parquet part files of one folder."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)

    def parts(self) -> list[Path]:
        return sorted(self.folder.glob("part-*.parquet")) if self.folder.is_dir() else []

    def keys(self) -> set[str]:
        """``run_key`` of every stored run."""
        keys: set[str] = set()
        for part in self.parts():
            keys.update(pq.read_table(part, columns=["run_key"]).column("run_key").to_pylist())
        return keys

    def append(self, rows: list[dict]) -> Path | None:
        """Write ``rows`` as one new part file (atomically); None when there are none."""
        if not rows:
            return None
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"part-{time.time_ns()}-{os.getpid()}.parquet"
        temporary = path.with_suffix(".tmp")
        pq.write_table(pa.Table.from_pylist(rows), temporary)
        os.replace(temporary, path)
        return path

    def read(self, keys: set[str] | None = None) -> pa.Table:
        """All stored runs (one row per ``run_key``, the first stored), or those in ``keys``."""
        tables = [pq.read_table(part) for part in self.parts()]
        if not tables:
            return pa.table({"run_key": pa.array([], pa.string())})
        table = pa.concat_tables(tables, promote_options="default")
        seen: set[str] = set()
        take = []
        for index, key in enumerate(table.column("run_key").to_pylist()):
            if key not in seen and (keys is None or key in keys):
                seen.add(key)
                take.append(index)
        return table.take(take)
