"""Batches of frames: views × lightings, atomic writes, resume, optional Dask distribution.

A frame is *finished* when its PNG exists: outputs are written atomically
(temporary file + rename, :mod:`jkatana.io.atomic`) and the PNG last, so a
batch killed at any moment leaves only finished frames and temporary files,
never a truncated image. Re-running the same command skips finished frames.

Distribution uses Dask distributed (a ``LocalCluster`` by default, or an
existing scheduler's address to scale out); each worker loads the scene once
(cached) and renders whole frames. No home-made scheduler.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

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


def finished(job: Job) -> bool:
    return Path(job.stem).with_suffix(".png").is_file() and Path(job.stem).with_suffix(".exr").is_file()


def _render_job(prep, job: Job) -> dict:
    from jkatana.render.renderer import render_view, write_outputs

    t0 = time.perf_counter()
    frame = render_view(prep, job.view, job.views, job.light, job.lights)
    write_outputs(prep, frame, Path(job.stem), {"jkatana_view": f"{job.view}/{job.views}",
                                                "jkatana_light": f"{job.light}/{job.lights}"})
    return {"frame": job.name, "status": "rendered", "seconds": time.perf_counter() - t0,
            "shade_s": frame.timing["shade_s"], "pixels": frame.stats["pixels_shaded"]}


def run_batch_serial(scene: Scene, jobs: list[Job], *, mode=None, samples=None, force=False,
                     progress: bool = True) -> list[dict]:
    """Render ``jobs`` in this process with a tqdm progress bar; finished frames are skipped."""
    from tqdm import tqdm

    from jkatana.render.renderer import prepare

    todo = [j for j in jobs if force or not finished(j)]
    results = [{"frame": j.name, "status": "skipped (finished)", "seconds": 0.0} for j in jobs if j not in todo]
    if not todo:
        return results
    t0 = time.perf_counter()
    prep = prepare(scene, mode=mode, samples=samples)
    results.append({"frame": "(load scene)", "status": "", "seconds": time.perf_counter() - t0})
    for job in tqdm(todo, desc="frames", unit="frame", disable=not progress):
        results.append(_render_job(prep, job))
    return results


def _worker_render(scene_path: str, output_dir: str, job: Job, mode, samples) -> dict:
    """Dask task: load (cached per worker) and render one frame."""
    from jkatana.render.renderer import _cached_prepare

    prep = _cached_prepare(scene_path, mode, samples)
    prep.scene = prep.scene.with_output_directory(output_dir)
    return _render_job(prep, job)


def run_batch_dask(scene_path, scene: Scene, jobs: list[Job], *, mode=None, samples=None, force=False,
                   scheduler: str | None = None, workers: int = 1) -> list[dict]:
    """Render ``jobs`` on a Dask cluster (``LocalCluster(workers)`` or ``scheduler``), tqdm over completions."""
    from dask.distributed import Client, LocalCluster, as_completed
    from tqdm import tqdm

    todo = [j for j in jobs if force or not finished(j)]
    results = [{"frame": j.name, "status": "skipped (finished)", "seconds": 0.0} for j in jobs if j not in todo]
    if not todo:
        return results
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(scheduler or cluster)
    try:
        futures = [client.submit(_worker_render, str(Path(scene_path).resolve()),
                                 str(Path(scene.output.directory).resolve()), j, mode, samples, pure=False)
                   for j in todo]
        for fut in tqdm(as_completed(futures), total=len(futures), desc="frames", unit="frame"):
            results.append(fut.result())
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
