"""Assemble a horizon-nav MCAP log from a mapping file: read, convert, validate, write.

Steps of :func:`import_flight`:

1. read the IMU and GPS tables (``tables``), plan each camera's footage (``footage``: stamps only,
   nothing decoded yet) and load the camera files;
2. validate (``validate``): the report is returned, printed by the command and optionally saved;
   errors stop the import (nothing is written) unless ``force``;
3. write the log (``scenarios.flightlog.writer.LogWriter``, kind ``"real"``): ``/tf_static`` (camera
   mounts q_bc) and ``/camera_<k>/camera_info`` at the first stamp, then the IMU, GPS and image
   messages window by window in time order (``LogWriter.advance``), so a long video is streamed, not
   held in memory. The mapping text and the report go into the metadata (``mapping``,
   ``import_report``).

A bad frame or a video shorter than declared is found while writing: the log is discarded (nothing
at the output path) unless ``keep_partial``, which finalises a valid log of everything before the
failing window (``horizon-nav.status.complete = "false"``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenarios.config.camera import load_camera, read_payload_mask
from scenarios.errors import UserError

from .footage import Footage, plan_footage
from .mapping import Mapping, load_mapping
from .plausibility import check_times
from .tables import GpsData, ImuData, read_gps, read_imu
from .validate import Report, validate


class ValidationFailed(UserError):
    """The validation report has errors (``.report`` holds it)."""

    def __init__(self, message: str, report: Report):
        super().__init__(message)
        self.report = report


@dataclass
class Prepared:
    """Everything read from the inputs, before writing."""
    mapping: Mapping
    imu: ImuData | None
    gps: GpsData | None
    cameras: list  # [(CameraSpec, FisheyeCamera, Footage | None)]
    report: Report
    timings: dict = field(default_factory=dict)
    masks: dict = field(default_factory=dict)  # camera k -> (H, W) bool payload mask

    @property
    def footages(self) -> list[Footage]:
        return [f for _, _, f in self.cameras if f is not None]


@dataclass
class ImportResult:
    path: Path | None
    prepared: Prepared
    counts: dict
    timings: dict

    @property
    def report(self) -> Report:
        return self.prepared.report


def prepare(mapping: Mapping) -> Prepared:
    """Read and convert every input and validate (no log written)."""
    tm = {}
    t = time.perf_counter()
    check_times(mapping)
    tm["time_check_s"] = time.perf_counter() - t
    t = time.perf_counter()
    imu = read_imu(mapping.imu, mapping.liftoff_ns) if mapping.imu else None
    tm["imu_read_s"] = time.perf_counter() - t
    t = time.perf_counter()
    gps = read_gps(mapping.gps, mapping.liftoff_ns) if mapping.gps else None
    tm["gps_read_s"] = time.perf_counter() - t
    cams, masks = [], {}
    for cs in mapping.cameras:
        cam = load_camera(cs.camera_file)
        fp = plan_footage(cs.footage, cs.k, cam.width, cam.height, mapping.liftoff_ns) if cs.footage else None
        cams.append((cs, cam, fp))
        if cs.payload_mask is not None:
            masks[cs.k] = read_payload_mask(cs.payload_mask, cam, f"{mapping.path}: cameras (k = {cs.k})"
                                            f".payload_mask: {cs.payload_mask}", "the camera file's")
    t = time.perf_counter()
    rep = validate(imu, gps, [f for *_, f in cams if f is not None], checks=mapping.checks,
                   liftoff_ns=mapping.liftoff_ns,
                   gyro_unit=mapping.imu.gyro.unit if mapping.imu else "rad/s",
                   accel_unit=mapping.imu.accel.unit if mapping.imu else "m/s^2", gps_spec=mapping.gps)
    tm["validate_s"] = time.perf_counter() - t
    return Prepared(mapping, imu, gps, cams, rep, tm, masks)


def _windows(t0: int, t1: int, window_s: float, streams=()):
    """Window ends from ``t0`` in steps of ``window_s`` up to past ``t1``, skipping the windows in
    which no stream in ``streams`` (sorted stamp arrays) has a stamp: the loop runs at most once
    per stamp and once per non-empty window, whatever the time between the first and last stamps."""
    step = int(window_s * 1e9)
    pos = [0] * len(streams)
    edge = t0 + step
    while edge <= t1:
        yield edge
        nxt = t1
        for j, s in enumerate(streams):
            pos[j] = int(np.searchsorted(s, edge, side="left"))
            if pos[j] < len(s):
                nxt = min(nxt, int(s[pos[j]]))
        # the window holding the next stamp (the current one when it is not empty yet)
        edge = max(edge + step, t0 + ((nxt - t0) // step + 1) * step)
    yield t1 + 1


def write_log(prep: Prepared, output: Path, *, keep_partial: bool = False, window_s: float = 10.0,
              compression: str = "zstd", progress=None) -> dict:
    """Write the prepared data as an MCAP log (module docstring); returns message counts."""
    from scenarios.flightlog.writer import LogWriter

    m = prep.mapping
    imu, gps = prep.imu, prep.gps
    firsts = [s[0] for s in ([imu.t_ns] if imu else []) + ([gps.t_ns] if gps else [])
              + [f.t_ns for f in prep.footages] if len(s)]
    lasts = [s[-1] for s in ([imu.t_ns] if imu else []) + ([gps.t_ns] if gps else [])
             + [f.t_ns for f in prep.footages] if len(s)]
    if not firsts:
        raise UserError(f"{m.path}: nothing to write (no samples, fixes or frames)")
    t0, t1 = int(min(firsts)), int(max(lasts))
    meta = {"scenario": "", "seed": "", "liftoff_utc_ns": m.liftoff_ns, "kind": "real", "name": m.name,
            "description": m.description, "mapping": m.text, "import_report": prep.report.to_json()}
    if imu is not None:
        meta["imu_output"] = imu.output
        meta["imu_sample"] = "point" if m.imu.imu_sample == "point" else "average"
    if gps is not None and not gps.has_velocity:
        meta["gps_velocity"] = "none"
    counts = {"imu": 0, "gps": 0, **{f"camera_{cs.k}": 0 for cs, _, _ in prep.cameras}}
    with LogWriter(output, meta, compression=compression, partial_on_error=keep_partial) as w:
        if prep.cameras:
            w.write_tf_static(np.array([t0], np.int64), {cs.k: (cs.translation_m, cs.q_bc) for cs, _, _ in prep.cameras})
        for cs, cam, _ in prep.cameras:
            w.write_camera(cs.k, np.array([t0], np.int64), cam)
            if cs.k in prep.masks:
                w.write_payload_mask(cs.k, t0, prep.masks[cs.k])
        gens = [(cs.k, iter(fp.frames())) for cs, _, fp in prep.cameras if fp is not None]
        nxt = [next(g, None) for _, g in gens]
        lo_i = lo_g = 0
        streams = [s for s in ([imu.t_ns] if imu else []) + ([gps.t_ns] if gps else [])
                   + [f.t_ns for f in prep.footages] if len(s)]
        for edge in _windows(t0, t1, window_s, streams):
            if imu is not None:
                hi = int(np.searchsorted(imu.t_ns, edge))
                if hi > lo_i:
                    s = slice(lo_i, hi)
                    if imu.output == "increment":
                        w.write_imu_increment(imu.t_ns[s], imu.gyro[s], imu.accel[s], imu.dt[s])
                    else:
                        w.write_imu(imu.t_ns[s], imu.gyro[s], imu.accel[s])
                    counts["imu"] += hi - lo_i
                    lo_i = hi
            if gps is not None:
                hi = int(np.searchsorted(gps.t_ns, edge))
                if hi > lo_g:
                    s = slice(lo_g, hi)
                    w.write_gps(gps.t_ns[s], gps.position[s], gps.velocity[s], gps.position_cov[s],
                                gps.velocity_cov[s], num_satellites=gps.num_satellites[s], status=0)
                    counts["gps"] += hi - lo_g
                    lo_g = hi
            for j, (k, g) in enumerate(gens):
                stamps, imgs = [], []
                try:
                    while nxt[j] is not None and nxt[j][0] < edge:
                        stamps.append(nxt[j][0])
                        imgs.append(nxt[j][1])
                        nxt[j] = next(g, None)  # may raise on a bad frame: the good ones are kept below
                finally:
                    if stamps:
                        w.write_image(k, np.array(stamps, np.int64), imgs)
                        counts[f"camera_{k}"] += len(stamps)
            w.advance(edge)
            if progress:
                progress(min(1.0, (edge - t0) / max(t1 + 1 - t0, 1)), "write")
    return counts


def import_flight(mapping: Mapping | str | Path, output: str | Path, *, keep_partial: bool = False,
                  force: bool = False, report_dir: str | Path | None = None, window_s: float = 10.0,
                  progress=None) -> ImportResult:
    """Import a flight described by a mapping file into the MCAP log ``output`` (module docstring).

    Raises ``ValidationFailed`` (a UserError, nothing written) when the report has errors and
    neither ``force`` nor ``[checks] errors_fatal = false``; ``UserError`` for bad input.
    """
    m = mapping if isinstance(mapping, Mapping) else load_mapping(mapping)
    output = Path(output)
    prep = prepare(m)
    if report_dir is not None:
        from .validate import save_report
        save_report(prep.report, Path(report_dir), prep.imu, prep.gps, prep.footages)
    errs = prep.report.errors
    if errs and m.checks.errors_fatal and not force:
        msg = "; ".join(f"{f.stream} {f.check}: {f.message}" for f in errs)
        raise ValidationFailed(f"{m.path}: validation found {len(errs)} error(s), nothing written "
                               f"(force=True imports anyway): {msg}", prep.report)
    t = time.perf_counter()
    try:
        counts = write_log(prep, output, keep_partial=keep_partial, window_s=window_s, progress=progress)
    except UserError as exc:
        tail = (f" (partial log kept at {output}: keep_partial=True)" if keep_partial
                else " (nothing written; keep_partial=True keeps what was imported before the error)")
        raise UserError(f"{exc}{tail}") from None
    prep.timings["write_s"] = time.perf_counter() - t
    notes = [(f"camera_{fp.k}", *n) for fp in prep.footages if (n := fp.depth_note()) is not None]
    for stream, level, msg in notes:   # known only once the frames are read
        prep.report.add(level, stream, "bit_depth", msg)
    if notes and report_dir is not None:     # again, with the notes (report.png counts the warnings)
        from .validate import save_report
        save_report(prep.report, Path(report_dir), prep.imu, prep.gps, prep.footages)
    return ImportResult(output, prep, counts, prep.timings)
