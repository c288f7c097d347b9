"""Per-run results on disk as Parquet (pyarrow), one row per run, appended as runs finish.

A store is a folder of immutable part files (``part-<ns>-<pid>.parquet``), each written to a
temporary name and renamed, so an interrupted sweep leaves only whole files and the next call
resumes from them. Every row carries ``run_key``, a digest of everything the run depends on
(:func:`run_key`), so a second call skips the runs already stored, and two sweeps that share a
cell share its runs. Parts written by different sweeps may have different columns; reading
unifies them (missing columns are null). :func:`fly_missing` is the one loop that flies what a
store lacks (a sweep's grid, a fit's candidates) and appends it as it finishes.
"""
from __future__ import annotations

import hashlib
import os
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from fcmpc.montecarlo.engines import Engine, run_all
from fcmpc.montecarlo.runs import RunRow, RunSpec

__all__ = ["Flown", "RunStore", "fly_missing", "run_key"]


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


@dataclass(frozen=True)
class Flown:
    """What :func:`fly_missing` did: ``rows`` of the runs it flew (by index into its specs), how many
    were ``planned`` and ``skipped`` (already stored), and the wall seconds it took."""

    rows: dict[int, RunRow]
    planned: int
    skipped: int
    wall_s: float


def fly_missing(specs: Sequence[RunSpec], keys: Sequence[str], store: RunStore | None, engine: Engine,
                columns: Sequence[Mapping] | None = None, desc: str = "runs", progress: bool = True,
                flush_every: int = 64, flush_s: float = 30.0) -> Flown:
    """Fly each ``specs[i]`` whose ``keys[i]`` (its :func:`run_key`) ``store`` does not hold (None: no
    store, fly all), appending ``{"run_key", **columns[i], **the RunRow}`` as runs finish, in parts of
    ``flush_every`` rows or ``flush_s`` seconds; an interruption keeps every finished run."""
    done = store.keys() if store is not None else set()
    todo = [(i, spec) for i, spec in enumerate(specs) if keys[i] not in done]
    started = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(specs), initial=len(specs) - len(todo), unit="run", file=sys.stderr, desc=desc)
    rows: dict[int, RunRow] = {}
    pending: list[dict] = []
    last_flush = time.monotonic()
    try:
        for index, output in run_all(todo, engine):
            rows[index] = output.row
            pending.append({"run_key": keys[index], **(columns[index] if columns else {}), **asdict(output.row)})
            if bar is not None:
                bar.update()
            if store is not None and (len(pending) >= flush_every or time.monotonic() - last_flush > flush_s):
                store.append(pending)
                pending, last_flush = [], time.monotonic()
    finally:
        if store is not None:
            store.append(pending)
        if bar is not None:
            bar.close()
    return Flown(rows, len(specs), len(specs) - len(todo), time.perf_counter() - started)
