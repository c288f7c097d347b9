"""Several sources behind one: e.g. the MPU9250 and the u-blox of the paper's device."""
from __future__ import annotations

from collections.abc import Sequence

from companion.io.sensors.base import Sample, SensorError, SensorSource

__all__ = ["CombinedSource"]


class CombinedSource(SensorSource):
    """Opens, polls and closes its sources together; samples keep their own kinds.

    Time bases: the direct hardware sources all stamp with the host monotonic clock, so
    their combination shares one clock. Combining a replay with live hardware would not,
    and is refused.
    """

    def __init__(self, sources: Sequence[SensorSource], name: str | None = None) -> None:
        super().__init__()
        if not sources:
            raise ValueError("CombinedSource needs at least one source")
        bases = {s.time_base for s in sources}
        if len(bases) > 1:
            raise ValueError(f"CombinedSource cannot mix time bases {sorted(bases)}: "
                             "their samples' time_s would not be comparable")
        self.sources = list(sources)
        self.name = name or "+".join(s.name for s in self.sources)
        self.time_base = self.sources[0].time_base

    @property
    def provides(self) -> frozenset:   # type: ignore[override]
        """What any of its sources delivers."""
        return frozenset().union(*(s.provides for s in self.sources))

    @property
    def finished(self) -> bool:
        return all(s.finished for s in self.sources)

    def open(self) -> None:
        opened: list[SensorSource] = []
        try:
            for source in self.sources:
                source.open()
                opened.append(source)
        except SensorError:
            for source in reversed(opened):
                source.close()
            raise

    def close(self) -> None:
        for source in self.sources:
            source.close()

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        """Everything ready now; if nothing is, wait on each source for a share of the timeout."""
        live = [s for s in self.sources if not s.finished]
        out: list[Sample] = []
        for source in live:
            out += source.poll(0.0)
        if not out and timeout_s > 0.0 and live:
            share = timeout_s / len(live)
            for source in live:
                out += source.poll(share)
                if out:
                    break
        self.stats.count(out)
        return out
