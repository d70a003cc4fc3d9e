"""Batches of frames: views × lightings, atomic writes, resume, optional Dask distribution.

A frame is *finished* when its EXR, its PNG and its record of inputs exist:
outputs are written atomically (temporary file + rename,
:mod:`jkatana.io.atomic`), the PNG after the EXR and the record last, so a
batch killed at any moment leaves only finished frames and temporary files,
never a truncated image. Re-running the same command skips finished frames —
only when they were made from the same inputs: the record (``.NAME.inputs.json``
beside the frame) holds every scene field, the shading mode, samples, view
and lighting, and the size and modification time of every file the scene
names. A finished frame whose record differs is not silently kept or
overwritten: the batch is refused up front, naming the frames and the
fields that changed, unless ``force`` re-renders them.

Distribution uses Dask distributed (a ``LocalCluster`` by default, or an
existing scheduler's address to scale out); each worker loads the scene once
(cached) and renders whole frames. No home-made scheduler.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

from jkatana.errors import InputError
from jkatana.io.atomic import write_text
from jkatana.render.scene import Scene


@dataclasses.dataclass(frozen=True)
class Job:
    view: int
    views: int
    light: int
    lights: int
    stem: str

    @property
    def name(self) -> str:
        return Path(self.stem).name


def plan_batch(scene: Scene, views: int, lights: int) -> list[Job]:
    """Frame jobs; a single frame keeps the scene's output name, a batch adds ``_vNNN_lNNN``."""
    out = Path(scene.output.directory)
    name = scene.output.name
    if views == 1 and lights == 1:
        return [Job(0, 1, 0, 1, str(out / name))]
    return [Job(v, views, l, lights, str(out / f"{name}_v{v:03d}_l{l:03d}"))
            for v in range(views) for l in range(lights)]


def record_path(job: Job) -> Path:
    """The record of the inputs a frame was made from, beside it."""
    stem = Path(job.stem)
    return stem.with_name(f".{stem.name}.inputs.json")


def finished(job: Job) -> bool:
    return (Path(job.stem).with_suffix(".png").is_file() and Path(job.stem).with_suffix(".exr").is_file()
            and record_path(job).is_file())


def _flatten(value, prefix: str, out: dict) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(v, f"{prefix}.{k}" if prefix else str(k), out)
    else:
        out[prefix] = value


def scene_inputs(scene: Scene, *, mode=None, samples=None) -> dict:
    """Everything that decides a frame's pixels, flat and JSON-comparable (no output location).

    The scene's fields (:meth:`Scene.to_dict`, the file's schema), the effective shading mode and samples
    (command-line overrides applied), and for each file the scene names its size and
    modification time (a replaced environment map or mesh changes the frame too).
    """
    flat: dict = {}
    _flatten(scene.to_dict(), "", flat)
    flat = {k: v for k, v in flat.items() if not k.startswith("output.directory")}
    flat["mode (effective)"] = mode or scene.render.mode
    flat["samples (effective)"] = samples or scene.render.samples
    base = Path(scene.path).parent if getattr(scene, "path", None) else Path.cwd()
    for key, value in list(flat.items()):
        if isinstance(value, str) and value and "\x00" not in value and len(value) < 4096:
            p = Path(value) if os.path.isabs(value) else base / value
            try:
                if p.is_file():
                    st = p.stat()
                    flat[f"file {key}"] = [st.st_size, st.st_mtime_ns]
            except OSError:
                pass
    return json.loads(json.dumps(flat, default=str, sort_keys=True))


def _job_inputs(inputs: dict, job: Job) -> dict:
    return {**inputs, "view": f"{job.view}/{job.views}", "light": f"{job.light}/{job.lights}"}


def _changed(old: dict, new: dict) -> list[str]:
    return sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))


def plan_resume(jobs: list[Job], inputs: dict, *, force: bool = False) -> tuple[list[Job], list[dict]]:
    """``(todo, skipped results)``: frames finished from the same inputs are skipped; a finished
    frame made from other inputs is an :class:`InputError` naming it and the changed fields
    (``force``: re-render everything)."""
    if force:
        return list(jobs), []
    todo, skipped, stale = [], [], []
    for job in jobs:
        if not finished(job):
            todo.append(job)
            continue
        try:
            old = json.loads(record_path(job).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            old = {}
        changed = _changed(old if isinstance(old, dict) else {}, _job_inputs(inputs, job))
        if changed:
            stale.append((job, changed))
        else:
            skipped.append({"frame": job.name, "status": "skipped (finished)", "seconds": 0.0})
    if stale:
        job, changed = stale[0]
        more = f" (and {len(stale) - 1} more frame(s))" if len(stale) > 1 else ""
        shown = ", ".join(changed[:6]) + (f", … {len(changed) - 6} more" if len(changed) > 6 else "")
        raise InputError(f"frame {job.name!r}{more} was rendered from other inputs (changed: {shown}); "
                         "--force re-renders, or give another --output", path=Path(job.stem).parent,
                         field="--output")
    return todo, skipped


def _record(job: Job, inputs: dict) -> None:
    write_text(record_path(job), json.dumps(_job_inputs(inputs, job), indent=1, sort_keys=True))


def _render_job(prep, job: Job, inputs: dict | None = None) -> dict:
    from jkatana.render.renderer import render_view, write_outputs

    t0 = time.perf_counter()
    frame = render_view(prep, job.view, job.views, job.light, job.lights)
    write_outputs(prep, frame, Path(job.stem), {"jkatana_view": f"{job.view}/{job.views}",
                                                "jkatana_light": f"{job.light}/{job.lights}"})
    if inputs is not None:
        _record(job, inputs)
    return {"frame": job.name, "status": "rendered", "seconds": time.perf_counter() - t0,
            "shade_s": frame.timing["shade_s"], "pixels": frame.stats["pixels_shaded"]}


def run_batch_serial(scene: Scene, jobs: list[Job], *, mode=None, samples=None, force=False,
                     progress: bool = True, max_memory=None) -> list[dict]:
    """Render ``jobs`` in this process with a tqdm progress bar; finished frames are skipped
    (:func:`plan_resume`); ``max_memory`` as :func:`~jkatana.render.renderer.prepare`'s."""
    from tqdm import tqdm

    from jkatana.render.renderer import prepare

    inputs = scene_inputs(scene, mode=mode, samples=samples)
    todo, results = plan_resume(jobs, inputs, force=force)
    if not todo:
        return results
    t0 = time.perf_counter()
    prep = prepare(scene, mode=mode, samples=samples, max_memory=max_memory)
    results.append({"frame": "(load scene)", "status": "", "seconds": time.perf_counter() - t0})
    for job in tqdm(todo, desc="frames", unit="frame", disable=not progress):
        results.append(_render_job(prep, job, inputs))
    return results


def _worker_render(scene_path: str, output_dir: str, job: Job, mode, samples) -> dict:
    """Dask task: load (cached per worker) and render one frame."""
    from jkatana.render.renderer import _cached_prepare

    prep = _cached_prepare(scene_path, mode, samples)
    prep.scene = prep.scene.with_output_directory(output_dir)
    return _render_job(prep, job)


def run_batch_dask(scene_path, scene: Scene, jobs: list[Job], *, mode=None, samples=None, force=False,
                   scheduler: str | None = None, workers: int = 1, connect_timeout: float = 20.0) -> list[dict]:
    """Render ``jobs`` on a Dask cluster (``LocalCluster(workers)`` or ``scheduler``), tqdm over completions."""
    from dask.distributed import Client, LocalCluster, as_completed
    from tqdm import tqdm

    if workers < 1:
        raise InputError(f"must be >= 1, got {workers}", field="--workers")
    inputs = scene_inputs(scene, mode=mode, samples=samples)
    todo, results = plan_resume(jobs, inputs, force=force)
    if not todo:
        return results
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        client = Client(scheduler or cluster, timeout=connect_timeout)
    except (OSError, TimeoutError) as err:
        if cluster is not None:
            cluster.close()
        raise InputError(f"cannot reach the Dask scheduler within {connect_timeout:g} s "
                         f"({type(err).__name__})", field="--scheduler") from None
    try:
        futures = {client.submit(_worker_render, str(Path(scene_path).resolve()),
                                 str(Path(scene.output.directory).resolve()), j, mode, samples,
                                 pure=False): j for j in todo}
        for fut in tqdm(as_completed(futures), total=len(futures), desc="frames", unit="frame"):
            results.append(fut.result())
            _record(futures[fut], inputs)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return results


def summary_table(results: list[dict]) -> str:
    """A plain-text table of frames, status and seconds, with the total."""
    rows = [("frame", "status", "seconds", "shading s", "pixels")]
    for r in results:
        rows.append((r["frame"], r["status"], f"{r['seconds']:.2f}",
                     f"{r['shade_s']:.2f}" if "shade_s" in r else "", str(r.get("pixels", ""))))
    total = sum(r["seconds"] for r in results)
    n_done = sum(r["status"] == "rendered" for r in results)
    n_skip = sum(r["status"].startswith("skipped") for r in results)
    rows.append(("total", f"{n_done} rendered, {n_skip} skipped", f"{total:.2f}", "", ""))
    widths = [max(len(r[i]) for r in rows) for i in range(5)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
