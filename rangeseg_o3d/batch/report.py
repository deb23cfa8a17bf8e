"""Showing a batch as it runs and writing its summary table.

On a terminal a tqdm bar shows files done, files/s, the ETA and the failures so far;
elsewhere (logs, CI) one plain line per input. The summary table has one row per input
(:meth:`.task.InputSummary.row`): JSON Lines always, Parquet too when pyarrow is there.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from ..io.atomic import atomic_write
from ..result import counted

__all__ = ["Progress", "write_summary", "read_summary", "format_counts"]


def format_counts(row) -> str:
    """``ok: 5 planes, 1 cylinder, 0 spheres, 2 unfitted`` (:func:`~rangeseg_o3d.result.counted`) or the row's error."""
    if row.status == "failed":
        return f"FAILED: {row.error}"
    if row.status == "skipped":
        return "skipped (outputs exist)"
    kinds = (counted(row.planes, "plane"), counted(row.cylinders, "cylinder"), counted(row.spheres, "sphere"))
    return f"ok: {', '.join(kinds)}, {row.unfitted} unfitted"


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class Progress:
    """Progress of a batch on ``stream``: a bar on a terminal, plain lines otherwise.

    Parameters
    ----------
    total : number of inputs.
    stream : where to show it (standard error by default).
    bar : force (True) or refuse (False) the bar; None asks ``stream.isatty()``.
    """

    def __init__(self, total: int, *, stream=None, bar: bool | None = None):
        self.total, self.done, self.failed = total, 0, 0
        self.stream = stream if stream is not None else sys.stderr
        self.start = time.perf_counter()
        self._bar = None
        if bar is None:
            bar = bool(getattr(self.stream, "isatty", lambda: False)())
        if bar:
            try:
                from tqdm import tqdm
            except ImportError:  # the plain lines still say everything
                tqdm = None
            if tqdm is not None:
                # No monitor thread: worker processes may be forked while the bar runs.
                tqdm.monitor_interval = 0
                self._bar = tqdm(total=total, file=self.stream, unit="file", dynamic_ncols=True,
                                 smoothing=0.1, postfix={"failed": 0})

    def rate(self) -> float:
        """Inputs finished per second so far."""
        elapsed = time.perf_counter() - self.start
        return self.done / elapsed if elapsed > 0 else 0.0

    def update(self, row) -> None:
        """Count one finished input; a failure is always shown with its message."""
        self.done += 1
        self.failed += row.status == "failed"
        if self._bar is not None:
            if row.status == "failed":
                self._bar.write(f"error: {row.error}", file=self.stream)
            self._bar.set_postfix({"failed": self.failed}, refresh=False)
            self._bar.update(1)
            return
        rate = self.rate()
        eta = (self.total - self.done) / rate if rate > 0 else 0.0
        # The error message names the input already (once).
        text = f"error: {row.error}" if row.status == "failed" else f"{row.input}: {format_counts(row)}"
        print(f"[{self.done}/{self.total}] {text} "
              f"({rate:.2f} files/s, ETA {_duration(eta)}, {self.failed} failed)",
              file=self.stream, flush=True)

    def write(self, text: str, file=None) -> None:
        """Print ``text`` (to standard output by default) without breaking the bar."""
        file = file if file is not None else sys.stdout
        if self._bar is not None:
            self._bar.write(text, file=file)
        else:
            print(text, file=file, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


_PARQUET_COLUMNS = ("index", "input", "name", "status", "error", "height", "width", "n_valid",
                    "planes", "cylinders", "spheres", "unfitted", "read_s", "segment_s",
                    "write_s", "total_s", "cpu_s", "worker", "outputs", "stage_timings")


def write_summary(rows, path) -> list[Path]:
    """Write the rows (dicts, in input order) as JSON Lines at ``path`` and, when pyarrow is
    installed, as Parquet beside it (same stem, ``.parquet``); both atomic. Returns the files."""
    path = Path(path)
    rows = sorted(rows, key=lambda r: r["index"])
    with atomic_write(path, mode="w") as fh:
        for row in rows:
            fh.write(json.dumps(row, sort_keys=False) + "\n")
    written = [path]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    schema = pa.schema([
        ("index", pa.int64()), ("input", pa.string()), ("name", pa.string()),
        ("status", pa.string()), ("error", pa.string()), ("height", pa.int64()),
        ("width", pa.int64()), ("n_valid", pa.int64()), ("planes", pa.int64()),
        ("cylinders", pa.int64()), ("spheres", pa.int64()), ("unfitted", pa.int64()),
        ("read_s", pa.float64()), ("segment_s", pa.float64()), ("write_s", pa.float64()),
        ("total_s", pa.float64()), ("cpu_s", pa.float64()), ("worker", pa.string()), ("outputs", pa.list_(pa.string())),
        ("stage_timings", pa.string()),  # a JSON object: its keys depend on the segmenter
    ])
    table = pa.Table.from_pylist(
        [{**{k: row.get(k) for k in _PARQUET_COLUMNS},
          "stage_timings": json.dumps(row.get("stage_timings") or {})} for row in rows],
        schema=schema)
    parquet = path.with_suffix(".parquet")
    with atomic_write(parquet, mode="wb") as fh:
        pq.write_table(table, fh)
    written.append(parquet)
    return written


def read_summary(path) -> dict[str, dict]:
    """Rows of an earlier summary (JSON Lines) by input; {} if absent or unreadable."""
    rows = {}
    try:
        with open(path, encoding="utf-8") as fh:
            for line in fh:
                row = json.loads(line)
                rows[row["input"]] = row
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return rows
