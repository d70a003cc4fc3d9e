"""Measurement ingestion: RAW decode + ROI statistics throughput, memory, campaign ingest time.

Cases:

- ``decode_roi_10mp``: one 10.1-Mpixel 14-bit DNG (3888×2592, the Canon EOS
  40D's frame, the paper's camera) written by the synthetic goniometer with
  photon and read noise; decode through rawpy/LibRaw and reduce two
  512×512 ROIs (hiraji, hamon). Time per capture (median over repeats) and
  captures/s. The shipped path keeps only the union of the ROIs out of
  LibRaw's buffer and converts only that to float; it is measured against the
  *reference* path (the whole frame converted to float64, masks over the
  full frame): error (max relative difference of value and sigma) and time
  side by side. LibRaw's own unpacking (~70 ms for 10 Mpixel here) is common
  to both.
- ``decode_memory_10mp``: peak resident memory of a fresh process that
  decodes the 10-Mpixel DNG and reduces its ROIs, minus the same process's
  peak after its imports (so the number is what decoding costs).
- ``campaign_ingest``: the paper's protocol (1188 captures, 2376 rows). In
  quick mode a subset of captures is written at 10 Mpixel and ingested with
  1 and 2 worker processes, and the time per capture is *extrapolated* to
  1188 captures (``extrapolated: true``); the full mode also ingests the
  complete campaign at the default 64×64 frame size, unextrapolated.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._harness import record, timeit

FULL_PROTOCOL_CAPTURES = 1188


def _log(msg: str) -> None:
    print(f"[bench_measure] {msg}", file=sys.stderr, flush=True)


def _rois_10mp(width: int, height: int):
    cy = height // 2 - 256
    return {"hiraji": (width // 4 - 256, cy, 512, 512), "hamon": (3 * width // 4 - 256, cy, 512, 512)}


def _write_big(folder: Path, n: int, seed: int = 0) -> tuple[Path, list[Path]]:
    """``n`` 10-Mpixel DNG captures of the paper protocol's first pairs, plus their manifest."""
    from jkatana.measure.goniometer import EOS40D_SIZE, Sensor, auto_exposure, render_frame, write_dng
    from jkatana.measure.manifest import manifest_csv
    from jkatana.measure.protocol import paper_protocol
    from jkatana.measure.synthetic import capture_id, green_values

    W, H = EOS40D_SIZE
    sensor = Sensor(width=W, height=H, bits=14, full_well_e=20000.0, read_noise_dn=2.0)
    pairs = paper_protocol()[:: max(1, FULL_PROTOCOL_CAPTURES // n)][:n]
    ti = np.array([p[0] for p in pairs])
    tr = np.array([p[1] for p in pairs])
    vals = {r: green_values(ti, tr, r) for r in ("hiraji", "hamon")}
    rows, files = [], []
    rois = _rois_10mp(W, H)
    for i, (a, b) in enumerate(pairs):
        v = {r: float(vals[r][i]) for r in vals}
        t = auto_exposure(max(v.values()), sensor.gain, 0.5)
        path = folder / f"{capture_id(a, b)}.dng"
        write_dng(path, render_frame(v, t, sensor, np.random.default_rng([seed, i])), black=sensor.blacks,
                  white=sensor.white, exposure_s=t)
        files.append(path)
        for r in vals:
            rows.append(dict(file=str(path), region=r, theta_i_deg=a, theta_r_deg=b, roi=[rois[r]], exposure_s=t,
                             capture=capture_id(a, b), gain=sensor.gain))
    manifest = folder / "manifest.csv"
    manifest.write_text(manifest_csv(rows, folder=folder))
    return manifest, files


def _reference_stats(path: Path, rois) -> list[tuple[float, float]]:
    """Reference: whole frame to float64, per-photosite black, full-frame masks."""
    import rawpy

    with rawpy.imread(str(path)) as raw:
        dn = raw.raw_image_visible.astype(np.float64)
        colors = raw.raw_colors_visible.copy()
        black = np.asarray(raw.black_level_per_channel, np.float64)[colors]
        white = float(raw.white_level)
        green = np.isin(colors, [i for i, c in enumerate(raw.color_desc.decode()) if c == "G"])
    out = []
    for x, y, w, h in rois:
        m = np.zeros(dn.shape, bool)
        m[y:y + h, x:x + w] = True
        m &= green & (dn < white)
        v = (dn[m] - black[m]) / (white - black[m])
        out.append((v.mean(), v.std(ddof=1) / np.sqrt(v.size)))
    return out


_MEMORY_SCRIPT = r"""
import json, sys
from jkatana.measure.decode import read_frame, roi_stats
import rawpy, numpy

def hwm():  # VmHWM: this process's peak RSS (ru_maxrss would carry the parent's over exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0

base = hwm()
rois = [tuple(r) for r in json.loads(sys.argv[2])]
window = (min(r[1] for r in rois), max(r[1] + r[3] for r in rois), min(r[0] for r in rois), max(r[0] + r[2] for r in rois))
frame = read_frame(sys.argv[1], window=window)
stats = [roi_stats(frame, [r]) for r in rois]
print(json.dumps({"baseline_mb": base, "peak_mb": hwm()}))
"""


def run(quick: bool) -> list[dict]:
    from jkatana.measure.decode import read_frame, roi_stats
    from jkatana.measure.goniometer import EOS40D_SIZE, Sensor, simulate_campaign
    from jkatana.measure.ingest import measure

    records = []
    work = Path(tempfile.mkdtemp(prefix="bench_measure_"))
    try:
        W, H = EOS40D_SIZE
        n_big = 6 if quick else 24
        _log(f"writing {n_big} 10-Mpixel DNGs")
        t0 = time.perf_counter()
        manifest, files = _write_big(work, n_big)
        write_s = (time.perf_counter() - t0) / n_big
        one = files[0]
        rois = list(_rois_10mp(W, H).values())

        window = (min(r[1] for r in rois), max(r[1] + r[3] for r in rois),
                  min(r[0] for r in rois), max(r[0] + r[2] for r in rois))

        def fast():  # what ingest does: keep only the union of the ROIs, convert only them
            frame = read_frame(one, window=window)
            return [roi_stats(frame, [r]) for r in rois]

        t_fast = timeit(fast, repeats=3 if quick else 9, warmup=1)
        t_ref = timeit(lambda: _reference_stats(one, rois), repeats=3 if quick else 9, warmup=1)
        got = fast()
        ref = _reference_stats(one, rois)
        err_value = max(abs(g.mean - r[0]) / abs(r[0]) for g, r in zip(got, ref))
        err_sigma = max(abs(g.stderr - r[1]) / abs(r[1]) for g, r in zip(got, ref))
        case = {"frame": f"{W}x{H}", "bits": 14, "rois": "2 x 512x512", "file_mb": round(one.stat().st_size / 2**20, 1)}
        records.append(record("measure", {**case, "path": "roi-crop (shipped)"}, time_s=t_fast,
                              error={"value_rel_max": err_value, "sigma_rel_max": err_sigma},
                              reference="full-frame float64 decode", captures_per_s=1.0 / t_fast["median"],
                              dng_write_s=write_s))
        records.append(record("measure", {**case, "path": "full-frame float64 (reference)"}, time_s=t_ref,
                              captures_per_s=1.0 / t_ref["median"]))
        _log(f"decode+ROI: {t_fast['median'] * 1e3:.0f} ms/capture (reference {t_ref['median'] * 1e3:.0f} ms)")

        out = subprocess.run([sys.executable, "-c", _MEMORY_SCRIPT, str(one), json.dumps(rois)],
                             capture_output=True, text=True, check=True, env={**os.environ})
        mem = json.loads(out.stdout.strip().splitlines()[-1])
        records.append(record("measure", {**case, "what": "decode + ROI stats, fresh process"},
                              memory_mb={**mem, "decode_increment_mb": mem["peak_mb"] - mem["baseline_mb"]}))
        _log(f"memory: {mem}")

        for workers in (1, 2):
            t0 = time.perf_counter()
            table = measure(manifest, workers=workers)
            dt = time.perf_counter() - t0
            per = dt / n_big
            records.append(record("measure", {"campaign": "paper protocol, 10 Mpixel", "workers": workers,
                                              "captures_timed": n_big},
                                  time_s={"median": dt, "repeats": 1},
                                  per_capture_s=per, extrapolated=True,
                                  full_campaign_s=per * FULL_PROTOCOL_CAPTURES,
                                  full_campaign_captures=FULL_PROTOCOL_CAPTURES, rows=len(table)))
            _log(f"ingest 10 Mpixel, {workers} worker(s): {per:.3f} s/capture → "
                 f"{per * FULL_PROTOCOL_CAPTURES / 60:.1f} min for {FULL_PROTOCOL_CAPTURES} (extrapolated)")
        for f in files:
            f.unlink()

        small = work / "small"
        t0 = time.perf_counter()
        n_small = 1188 if not quick else 149
        protocol = None if not quick else [(15.0, b) for a, b in __import__(
            "jkatana.measure.protocol", fromlist=["paper_protocol"]).paper_protocol() if a == 15.0]
        simulate_campaign(small, protocol, sensor=Sensor(bits=14, full_well_e=20000.0, read_noise_dn=2.0))
        sim_s = time.perf_counter() - t0
        for workers in (1, 2):
            t0 = time.perf_counter()
            table = measure(small / "manifest.csv", workers=workers)
            dt = time.perf_counter() - t0
            records.append(record("measure", {"campaign": "paper protocol, 64x64 synthetic", "workers": workers,
                                              "captures_timed": n_small},
                                  time_s={"median": dt, "repeats": 1}, per_capture_s=dt / n_small,
                                  extrapolated=quick, full_campaign_s=dt / n_small * FULL_PROTOCOL_CAPTURES,
                                  simulate_s=sim_s, rows=len(table)))
            _log(f"ingest 64x64, {workers} worker(s): {dt:.2f} s for {n_small} captures")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return records
