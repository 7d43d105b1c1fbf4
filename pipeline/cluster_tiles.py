"""The normals stage of one session split into pixel tiles, for :mod:`pipeline.cluster`.

Three steps, each a separate (Dask) task; only the first and the last touch ``session.yaml``:

1. :func:`plan_normals` writes a scratch stack ``normals/.tiles/stack.npy`` (K, H, W) float32,
   ``valid.npy`` (K, H, W) bool and ``mask.npy`` (H, W) bool, frame by frame, and fits the
   method's shared context (the biquadratic shared shape) ONCE on the whole mask, exactly as
   :func:`pipeline.photometric.estimate_normals` does.
2. :func:`run_tile` memory-maps the scratch stack, reads only the rows its pixels lie in,
   solves them with that same context and writes ``normals/.tiles/tile-<p0>.npz`` atomically. A
   rerun (a worker died, Dask retried) finds the finished file and returns at once, or rewrites
   the same bytes.
3. :func:`assemble_normals` scatters the tiles into full maps, writes ``normals/`` exactly as
   :func:`pipeline.normals_stage.normals_session` does, records the stage and removes the scratch.

A tile is a run of consecutive object pixels (in row-major order) made of whole solver chunks
of :func:`pipeline.photometric.estimate_normals` (its ``chunk_size``), so every chunk the solver
sees holds the same pixels as in a serial run: the tiled outputs are byte-identical to the
serial stage's even where the solver's last bits depend on the chunk it is given.
"""

import inspect


import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .errors import InputError, StageError
from .imageio import read_mask
from .near_lights import PointLights, observations_at
from .normals_stage import LIGHTS, STAGE, _auto_mask, _inputs, _object_frames, _write_outputs, \
    light_model, load_object_stack, model_record, read_stage_lights, stage_params
from .photometric import STATUS, PhotometricResult, _allocate, _anchor_wanted, _method, _scatter, \
    estimate_normals, resolve_selection
from .ps_anchor import first_verdict, highlight_mismatch
from .session import Session

__all__ = ["TilePlan", "plan_normals", "run_tile", "assemble_normals", "pixel_tiles", "write_stack",
           "SCRATCH", "WHOLE_IMAGE", "serial_chunk_size"]

SCRATCH = "normals/.tiles"
#: :func:`assemble_normals`' answer when the lights need the specular-peak correction
#: (:mod:`pipeline.ps_anchor`): one global scale, applied to every pixel, that only a solve of
#: the whole image can make; the caller then runs the serial normals stage. :func:`plan_normals`
#: answers it before any tile for near lights placed at an integrated depth, for the same reason.
WHOLE_IMAGE = "whole-image"


@dataclass
class TilePlan:
    """Everything a tile task needs; small enough to ship to every worker.

    ``lights`` (K, 3) are the used lights' unit directions (camera frame); ``options`` the
    solver options after :func:`pipeline.photometric.resolve_selection`; ``context`` the
    method's shared context; ``tiles`` the :func:`pixel_tiles` of the mask; ``chunk`` the
    pixels per solver call; ``params``/``inputs``/``extra`` go to the stage record; ``anchor``
    whether tiles also measure the specular-peak mismatches of :mod:`pipeline.ps_anchor`.
    """

    root: str
    method: str
    options: dict
    lights: np.ndarray
    context: dict
    shape: tuple
    tiles: list
    params: dict
    inputs: dict
    chunk: int
    extra: dict = field(default_factory=dict)
    started: float = 0.0
    anchor: bool = False

    def scratch(self, name=""):
        return Path(self.root) / SCRATCH / name


def serial_chunk_size():
    """Pixels per solver call in a serial run: estimate_normals' default ``chunk_size``."""
    return inspect.signature(estimate_normals).parameters["chunk_size"].default


def pixel_tiles(mask, tile_pixels, chunk):
    """Tiles of the mask's pixels: [(p0, r0, r1, skip, count), ...].

    A tile holds the ``count`` object pixels numbered p0.. in row-major order (p0 a multiple
    of ``chunk``; ``count`` about ``tile_pixels`` rounded to whole chunks). They lie in rows
    [r0, r1), after the first ``skip`` object pixels of those rows.
    """
    per_row = np.count_nonzero(mask, axis=1)
    before = np.concatenate([[0], np.cumsum(per_row)])  # object pixels before each row
    total, step = int(before[-1]), max(1, int(tile_pixels) // chunk) * chunk
    tiles = []
    for p0 in range(0, total, step):
        count = min(step, total - p0)
        r0 = int(np.searchsorted(before, p0, side="right")) - 1
        r1 = int(np.searchsorted(before, p0 + count - 1, side="right"))
        tiles.append((p0, r0, r1, p0 - int(before[r0]), count))
    return tiles


def write_stack(folder, frames, load, name=str):
    """Write stack.npy (K, H, W) float32 and valid.npy (K, H, W) bool one frame at a time.

    ``load(frame)`` returns (image (H, W) float32, valid (H, W) bool); ``name(frame)`` names a
    frame in errors. Both files are written atomically; only one frame is in memory at once.
    Returns the per-pixel peak (H, W) over the frames.
    """
    folder = Path(folder)
    with atomic_path(folder / "stack.npy") as tmp_stack, atomic_path(folder / "valid.npy") as tmp_valid:
        stack = valid = peak = None
        for k, frame in enumerate(frames):
            image, ok = load(frame)
            if stack is None:
                shape = (len(frames),) + image.shape
                stack = np.lib.format.open_memmap(tmp_stack, mode="w+", dtype=np.float32, shape=shape)
                valid = np.lib.format.open_memmap(tmp_valid, mode="w+", dtype=bool, shape=shape)
                peak = image.copy()
            if image.shape != stack.shape[1:]:
                raise StageError(f"{name(frame)}: size {image.shape} differs from "
                                 f"{name(frames[0])}'s {stack.shape[1:]}")
            stack[k], valid[k] = image, ok
            np.maximum(peak, image, out=peak)
        stack.flush()
        valid.flush()
        del stack, valid
    return peak


def plan_normals(session, options, *, force=False, tile_pixels=1 << 18, chunk=None):
    """Prepare the tiled normals stage; returns a :class:`TilePlan`, None when up to date, or
    :data:`WHOLE_IMAGE` when the stage must run whole (near lights placed at the integrated
    depth of a first solve, :mod:`pipeline.near_depth`).

    ``options`` are the normals stage options (``method``, ``t_low``, ...; None = default);
    ``chunk`` the pixels per solver call (default: :func:`serial_chunk_size`).
    """
    options = {k: v for k, v in options.items() if v is not None}
    method = options.pop("method", "biquadratic")
    frames = _object_frames(session)
    mask_rel = session.manifest["lights"].get("object_mask")
    lights_model = options.pop("lights_model", "auto")
    near_depth = options.pop("near_depth", True)
    params = stage_params(method, lights_model, options, near_depth)
    inputs = _inputs(session, frames, mask_rel)
    if not force and session.stage_is_current(STAGE, params, inputs):
        return None
    started = time.time()
    lights, used = read_stage_lights(session, frames)
    model = light_model(lights, lights_model)
    folder = session.root / SCRATCH
    shutil.rmtree(folder, ignore_errors=True)  # tiles of an older plan must not be reused
    if model == "near" and near_depth:
        return WHOLE_IMAGE
    folder.mkdir(parents=True)
    peak = write_stack(folder, used, lambda frame: _load_frame(session, frame, lights),
                       name=session.linear_path)
    mask = read_mask(session.path(mask_rel)) if mask_rel else _auto_mask(peak[None])
    if mask.shape != peak.shape:
        raise StageError(f"{session.path(mask_rel)}: mask size {mask.shape} differs from the frames' {peak.shape}")
    if not mask.any():
        raise InputError(f"{session.root}: normals: the mask has no pixels")
    with atomic_path(folder / "mask.npy") as tmp:
        np.save(tmp, mask)
    chosen = [f["light"] for f in used]
    directions = _unit_directions(session, lights.directions[chosen])
    solved = resolve_selection(directions, options)
    if model == "near":
        directions = PointLights(lights.positions[chosen], mask.shape)
        solved = resolve_selection(directions.central_directions, options)
    anchor = _anchor_wanted(method, solved.pop("specular_anchor", "auto"), solved, directions,
                            directions if model == "near" else None)
    context = _prepare(method, folder, mask, directions, solved)
    extra = {"lights_used": len(used), "lights_left_out": sorted(int(k) for k in lights.flags),
             "light_model": model}
    chunk = chunk or serial_chunk_size()
    return TilePlan(str(session.root), method, solved, directions, context, mask.shape,
                    pixel_tiles(mask, tile_pixels, chunk), params, inputs, chunk, extra, started, anchor)


def _unit_directions(session, directions):
    """(K, 3) unit vectors, with estimate_normals' checks (K >= 3, rank 3) and arithmetic."""
    directions = np.asarray(directions, dtype=float)
    if len(directions) < 3 or np.linalg.matrix_rank(directions, tol=1e-6) < 3:
        raise InputError(f"{session.path(LIGHTS)}: the {len(directions)} used lights do not span 3 "
                         "dimensions (fewer than 3, or coplanar): normals are not determined")
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def _load_frame(session, frame, lights):
    # the same arithmetic as the serial stage, one frame at a time
    images, valid = load_object_stack(session, [frame], lights)
    return images[0], valid[0]


def _prepare(method, folder, mask, lights, options):
    """The method's shared context from the whole mask, gathered from the memory-mapped stack."""
    solver = _method(method)
    if not hasattr(solver, "prepare"):
        return {}
    stack = np.load(folder / "stack.npy", mmap_mode="r")
    valid = np.load(folder / "valid.npy", mmap_mode="r")
    k = stack.shape[0]
    flat, flat_valid = stack.reshape(k, -1), valid.reshape(k, -1)

    def gather(idx):
        obs, per_pixel = observations_at(lights, flat[:, idx].T.astype(np.float64), idx)
        return obs, flat_valid[:, idx].T, per_pixel

    return solver.prepare(gather, np.flatnonzero(mask), **options)


def run_tile(plan, tile, hook=None):
    """Solve one tile (an item of ``plan.tiles``); returns the tile file's path (str).

    Reads only the tile's rows of the memory-mapped stack. ``hook(plan, tile)``, if given, is
    called after solving and before writing (tests use it to kill the worker mid-tile).
    """
    from threadpoolctl import threadpool_limits

    p0, r0, r1, skip, count = tile
    target = plan.scratch(f"tile-{p0:010d}.npz")
    if target.is_file():  # finished by an earlier attempt of this task
        return str(target)
    stack = np.load(plan.scratch("stack.npy"), mmap_mode="r")
    valid = np.load(plan.scratch("valid.npy"), mmap_mode="r")
    mask = np.load(plan.scratch("mask.npy"), mmap_mode="r")
    k, width = stack.shape[0], stack.shape[2]
    block, block_valid = stack[:, r0:r1].reshape(k, -1), valid[:, r0:r1].reshape(k, -1)
    local = np.flatnonzero(mask[r0:r1])[skip:skip + count]
    solver = _method(plan.method)
    pieces = []
    # one BLAS thread: a Dask worker is one core's worth of work
    with threadpool_limits(1):
        for start in range(0, len(local), plan.chunk):
            idx = local[start:start + plan.chunk]
            obs = block[:, idx].T.astype(np.float64)
            if not np.isfinite(obs).all():
                bad = int(np.argmin(np.isfinite(obs).all(axis=0)))
                raise InputError(f"{plan.root}: normals: image {bad} has non-finite pixel values "
                                 f"inside the mask (rows {r0}-{r1 - 1})")
            obs, lights = observations_at(plan.lights, obs, idx + r0 * width)
            piece = solver(obs, block_valid[:, idx].T, lights, context=plan.context, **plan.options)
            if plan.anchor:  # as estimate_normals measures it, chunk by chunk
                piece["mismatch"] = highlight_mismatch(obs, np.nan_to_num(piece["b"]), lights,
                                                       valid=block_valid[:, idx].T)
            pieces.append(piece)
    if hook is not None:
        hook(plan, tile)
    keys = ("b", "status", "used", "rss", "params") + (("mismatch",) if plan.anchor else ())
    arrays = {key: np.concatenate([p[key] for p in pieces]) for key in keys} if pieces else {}
    with atomic_path(target) as tmp:
        np.savez(tmp, idx=local + r0 * width, **arrays)
    return str(target)


def assemble_normals(plan, tile_paths=None):
    """Scatter the tiles into full maps, write ``normals/``, record the stage; returns the record.

    Returns :data:`WHOLE_IMAGE` instead (and writes nothing) when the tiles' specular-peak
    mismatches call for a correction of the lights.
    """
    session = Session.open(plan.root)
    mask = np.load(plan.scratch("mask.npy"))
    out, mismatch = None, []
    for tile in plan.tiles:
        path = plan.scratch(f"tile-{tile[0]:010d}.npz")
        if not path.is_file():
            raise StageError(f"{path}: normals: tile result is missing")
        with np.load(path) as tile:
            if tile["idx"].size == 0:
                continue
            chunk = {key: tile[key] for key in ("b", "status", "used", "rss", "params")}
            if out is None:
                out = _allocate(mask.shape, chunk["params"].shape[1])
            _scatter(out, tile["idx"], chunk)
            if plan.anchor:
                mismatch.append(tile["mismatch"])
    anchor = first_verdict(np.concatenate(mismatch) if mismatch else np.zeros(0)) if plan.anchor else None
    if anchor is not None and anchor["anchor"] == "to correct":
        shutil.rmtree(plan.scratch(), ignore_errors=True)
        return WHOLE_IMAGE
    result = PhotometricResult(normals=out["normals"], mask=mask, status=out["status"], albedo=out["albedo"],
                               params=out["params"], residual=out["residual"], used=out["used"],
                               method=plan.method, options=plan.options, shared_shape=plan.context.get("shape_paper"))
    outputs = _write_outputs(session, result)
    counts = {name: int(np.sum(result.status[mask] == code)) for name, code in STATUS.items() if code}
    extra = {"pixels": int(mask.sum()), "status_counts": counts, **plan.extra}
    extra.update(model_record(result.shared_shape, plan.context.get("shape_check"), anchor))
    record = session.record_stage(STAGE, plan.params, plan.inputs, outputs,
                                  seconds=time.time() - plan.started, **extra)
    shutil.rmtree(plan.scratch(), ignore_errors=True)
    return record
