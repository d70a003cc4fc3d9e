"""Manifest → measurement table: decode every capture, reduce its ROIs.

:func:`measure` validates the whole manifest first (cheap errors before any
decoding), then decodes each file once (a capture usually holds a hiraji and
a hamon ROI), optionally in several worker processes, and returns the table
in manifest order. Any bad capture raises one :class:`InputError` naming the
manifest, its row and the field; :func:`measure_to_file` writes the table
atomically only when every capture succeeded, so no partial table is left.
"""

from __future__ import annotations

import concurrent.futures as cf
import math
import multiprocessing
import os
from pathlib import Path
from typing import Callable

import numpy as np

from jkatana.errors import InputError
from jkatana.measure.decode import read_frame, roi_stats
from jkatana.measure.manifest import Entry, Manifest, read_manifest
from jkatana.measure.table import MeasurementTable, write_table


class _RowError(Exception):
    """An error at a manifest row, as plain picklable pieces."""

    def __init__(self, message: str, row: int, field: str):
        super().__init__(message, row, field)


def _measure_file(manifest_path: Path, entries: list[Entry]) -> list[dict]:
    """Decode one file and reduce every entry (region) that uses it.

    Runs in worker processes, so errors come back as data
    (``{"error": (message, row, field)}``), not as exceptions.
    """
    try:
        return _measure_entries(entries)
    except _RowError as err:
        return [{"error": err.args}]


def _bbox(entries: list[Entry]) -> tuple[int, int, int, int]:
    rects = [r for e in entries for r in e.rois]
    return (min(r[1] for r in rects), max(r[1] + r[3] for r in rects),
            min(r[0] for r in rects), max(r[0] + r[2] for r in rects))


def _measure_entries(entries: list[Entry]) -> list[dict]:
    window = _bbox(entries)  # decode only the union of this file's ROIs
    frame = None
    darks: dict[Path, object] = {}
    out = []
    for e in entries:
        if frame is None:
            try:
                frame = read_frame(e.file, black_level=e.black_level, white_level=e.white_level, window=window)
            except InputError as err:
                raise _RowError(str(err), e.row, "file") from None
        dark = None
        if e.dark is not None:
            if e.dark not in darks:
                try:
                    darks[e.dark] = read_frame(e.dark, black_level=e.black_level, white_level=e.white_level,
                                               window=window)
                except InputError as err:
                    raise _RowError(str(err), e.row, "dark") from None
            dark = darks[e.dark]
            if dark.shape != frame.shape:
                raise _RowError(f"dark frame {e.dark.name} is {dark.shape}, the capture {frame.shape}",
                                e.row, "dark")
        exposure = e.exposure_s if e.exposure_s is not None else frame.shutter_s
        if not (exposure and math.isfinite(exposure) and exposure > 0):
            raise _RowError(f"no exposure time given and none stored in {e.file.name}", e.row, "exposure_s")
        try:
            stats = roi_stats(frame, e.rois, dark=dark)
        except InputError as err:
            raise _RowError(f"{e.file.name}: {err}", e.row, "roi") from None
        out.append(dict(capture=e.capture, region=e.region, theta_i_deg=e.theta_i_deg,
                        theta_r_deg=e.theta_r_deg, value=e.gain * stats.mean / exposure,
                        sigma=e.gain * stats.stderr / exposure, n_pixels=stats.n_pixels,
                        n_saturated=stats.n_saturated, exposure_s=exposure, row=e.row))
    return out


def _raise(manifest: Manifest, error: tuple) -> None:
    message, row, field = error
    raise InputError(message, path=manifest.path, row=row, field=field)


def _leave_interrupts_to_parent() -> None:
    """Decoding workers ignore SIGINT: a Ctrl-C reaches the whole process group, and the parent ends
    the command cleanly (one line, workers terminated) instead of every worker printing a traceback."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def auto_workers(manifest: Manifest, *, min_bytes: int = 64 * 2**20) -> int:
    """2 decoding processes (or the usable cores, if fewer) when the captures total more
    than ``min_bytes``; else 1 — for small frames a process pool costs more than it saves
    (benchmarks/bench_measure.py)."""
    files = {e.file for e in manifest.entries}
    total = sum(f.stat().st_size for f in files)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return min(2, cores) if total > min_bytes else 1


def measure(manifest: str | Path | Manifest, *, workers: int | None = None,
            progress: Callable[[int], None] | None = None) -> MeasurementTable:
    """Ingest every capture of ``manifest`` into a :class:`MeasurementTable`.

    **Arguments:**

    - `manifest`: a manifest path (CSV/TOML) or a parsed :class:`Manifest`.
    - `workers`: processes to decode with (1 = in this process; None = :func:`auto_workers`).
    - `progress`: called with the number of *captures* (manifest rows) just finished.

    **Returns:** the table, rows in manifest order. Raises :class:`InputError`
    for the first bad row (in manifest order).
    """
    if not isinstance(manifest, Manifest):
        manifest = read_manifest(manifest)
    if workers is None:
        workers = auto_workers(manifest)
    groups: dict[Path, list[Entry]] = {}
    for e in manifest.entries:
        groups.setdefault(e.file, []).append(e)
    jobs = list(groups.values())
    results: list[list[dict]] = []
    if workers <= 1 or len(jobs) < 8:
        for entries in jobs:
            res = _measure_file(manifest.path, entries)
            if "error" in res[0]:
                _raise(manifest, res[0]["error"])
            results.append(res)
            if progress:
                progress(len(entries))
    else:
        # LibRaw is built with OpenMP: fork() after it is loaded can deadlock, so use forkserver.
        context = multiprocessing.get_context("forkserver")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                    initializer=_leave_interrupts_to_parent) as pool:
            chunk = max(1, min(32, len(jobs) // (4 * workers)))
            for entries, res in zip(jobs, pool.map(_measure_file, [manifest.path] * len(jobs), jobs,
                                                   chunksize=chunk)):
                if "error" in res[0]:
                    pool.shutdown(cancel_futures=True)
                    _raise(manifest, res[0]["error"])
                results.append(res)
                if progress:
                    progress(len(entries))
    rows = sorted((r for res in results for r in res), key=lambda r: r["row"])
    cols = {k: [r[k] for r in rows] for k in ("capture", "region", "theta_i_deg", "theta_r_deg", "value",
                                                "sigma", "n_pixels", "n_saturated", "exposure_s")}
    cols["n_pixels"] = np.asarray(cols["n_pixels"], np.int64)
    cols["n_saturated"] = np.asarray(cols["n_saturated"], np.int64)
    return MeasurementTable.from_columns(**cols).validate(manifest.path)


def measure_to_file(manifest: str | Path | Manifest, output: str | Path, *, workers: int | None = None,
                    progress: Callable[[int], None] | None = None) -> MeasurementTable:
    """:func:`measure`, then write the table atomically (nothing is written on error), and the manifest's
    instrument beside it (:func:`jkatana.measure.protocol.write_instrument`; ``jkatana fit`` reads it)."""
    from jkatana.measure.protocol import write_instrument

    manifest = manifest if isinstance(manifest, Manifest) else read_manifest(manifest)
    table = measure(manifest, workers=workers, progress=progress)
    write_table(table, output)
    write_instrument(output, manifest.instrument)
    return table


__all__ = ["measure", "measure_to_file"]
