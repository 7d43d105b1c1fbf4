"""The normals stage of one session split into pixel tiles, for :mod:`pipeline.cluster`.

The same stage as :func:`pipeline.photometric.stage.normals_session`, on the same engine: it begins
and records through :func:`pipeline.photometric.stage.begin_normals` and
:func:`pipeline.photometric.stage.record_normals`, plans the solve with
:func:`pipeline.photometric.estimate.plan_solve` and solves chunks with
:func:`pipeline.photometric.engine.solve_chunk`.

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
   :func:`pipeline.photometric.stage.normals_session` does, records the stage and removes the scratch.

A tile is a run of consecutive object pixels (in row-major order) made of whole solver chunks
(:data:`pipeline.photometric.engine.CHUNK_SIZE`), so every chunk the solver
sees holds the same pixels as in a serial run: the tiled outputs are byte-identical to the
serial stage's even where the solver's last bits depend on the chunk it is given.
"""

import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_path
from ..core.errors import InputError, StageError
from ..core.imageio import read_workers
from ..core.jit import single_threaded
from ..core.mapped import FrameByFrame, MappedNpy, create_npy
from ..core.paths import LIGHTS, TILES_SCRATCH
from ..core.session import Session
from .anchor import first_verdict
from .consensus import (CONSENSUS_RADIUS, CONSENSUS_ROUNDS, Veto, consensus_record, halo_pixels, solved,
                        vetoed_gatherer, vote_rounds)
from .engine import (CHUNK_KEYS, CHUNK_SIZE, SHARED_KEYS, allocate_maps, gatherer, phases_of, prepare_context,
                     scatter_chunk, solve_chunk)
from .estimate import check_lights, check_plan_frames, plan_solve, result_from_maps
from .stage import (STAGE, ChannelSums, NormalsRun, begin_normals, load_object_stack, object_mask, predict_held_out,
                    record_normals, registration_verdict, stack_shape)

__all__ = ["TilePlan", "plan_normals", "run_tile", "assemble_normals", "pixel_tiles", "write_stack", "stack_peak",
           "tile_context", "frame_check", "solve_tiled", "SCRATCH", "WHOLE_IMAGE"]

SCRATCH = TILES_SCRATCH
#: the scratch file of the frames' colour sums (:class:`pipeline.photometric.stage.ChannelSums`),
#: gathered while the stack is written, so that the albedo's colour needs no second read
CHANNELS = "channels.npy"
#: :func:`assemble_normals`' answer when the lights need the specular-peak correction
#: (:mod:`pipeline.photometric.anchor`): one global scale, applied to every pixel, that only a solve of
#: the whole image can make; the caller then runs the serial normals stage. The same when frames
#: the registration check found moved are to be aligned and solved again. :func:`plan_normals`
#: answers it before any tile for near lights placed at an integrated depth, for the same reason,
#: and :func:`assemble_normals` when run again after its scratch was removed without a record.
WHOLE_IMAGE = "whole-image"


#: object pixels per tile when the serial stage solves tiles (:func:`solve_tiled`): 2 ** 18
#: pixels x 96 lights read 100 MB of the stack at a time
SERIAL_TILE_PIXELS = 1 << 18


@dataclass
class TilePlan:
    """Everything a tile task needs; small enough to ship to every worker.

    ``solve`` is the :class:`pipeline.photometric.estimate.SolvePlan` (method, options after
    the selection policy, lights, whether tiles also measure the specular-peak mismatches);
    ``context`` the method's shared context; ``tiles`` the :func:`pixel_tiles` of the mask;
    ``chunk`` the pixels per solver call; ``run`` the stage's :class:`NormalsRun` (None when
    tiles are solved outside a session's stage, as the cluster benchmark does).
    """

    root: str
    solve: object
    context: dict
    shape: tuple
    tiles: list
    chunk: int = CHUNK_SIZE
    run: NormalsRun = None

    @property
    def anchor(self):
        return self.solve.anchor

    @property
    def params(self):
        return self.run.params

    def scratch(self, name=""):
        return Path(self.root) / SCRATCH / name


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


def write_stack(folder, shape, fill):
    """Write stack.npy (K, H, W) float32 and valid.npy (K, H, W) bool, atomically.

    ``fill(stack, valid, stored)`` fills the two files, mapped into memory, and calls
    ``stored(index)`` after each frame: the pages written so far go back to the page cache
    there, so that the writer holds only the frames in flight, not the stack.
    """
    folder = Path(folder)
    with atomic_path(folder / "stack.npy") as tmp_stack, atomic_path(folder / "valid.npy") as tmp_valid:
        create_npy(tmp_stack, shape, np.float32)
        create_npy(tmp_valid, shape, bool)
        with MappedNpy(tmp_stack, write=True) as stack, MappedNpy(tmp_valid, write=True) as valid:
            def stored(_):
                stack.release()
                valid.release()

            fill(stack.array, valid.array, stored)


def stack_peak(path, rows=256):
    """Each pixel's brightest observation (H, W) over the stack (K, H, W) in ``path``, read
    ``rows`` rows at a time (the pages read are given back after each band)."""
    with MappedNpy(path) as mapped:
        stack = mapped.array
        peak = np.empty(stack.shape[1:], stack.dtype)
        for r0 in range(0, stack.shape[1], rows):
            np.max(stack[:, r0:r0 + rows], axis=0, out=peak[r0:r0 + rows])
            mapped.release()
    return peak


def plan_normals(session, options, *, force=False, tile_pixels=1 << 18, chunk=CHUNK_SIZE, run=None):
    """Prepare the tiled normals stage; returns a :class:`TilePlan`, None when up to date, or
    :data:`WHOLE_IMAGE` when the stage must run whole (near lights placed at the integrated
    depth of a first solve, :mod:`pipeline.photometric.near_depth`).

    ``options`` are the normals stage options (``method``, ``t_low``, ...; None = default);
    ``chunk`` the pixels per solver call; ``run`` a :class:`NormalsRun` already begun (the serial
    stage's, when it chose tiles), else the stage is begun here.
    """
    options = {k: v for k, v in options.items() if v is not None}
    run = run or begin_normals(session, force=force, **options)
    if run is None:
        return None
    folder = session.path(SCRATCH)
    shutil.rmtree(folder, ignore_errors=True)  # tiles of an older plan must not be reused
    if run.model == "near" and run.near_depth:
        return WHOLE_IMAGE
    folder.mkdir(parents=True)
    channels = ChannelSums()
    shape = stack_shape(session, run.frames)[:3]
    write_stack(folder, shape,
                lambda stack, valid, stored: load_object_stack(session, run.frames, run.lights, channels,
                                                               out=(stack, valid), stored=stored))
    if channels.sums is not None and not channels.grey:   # the albedo's colour, for assemble_normals
        with atomic_path(folder / CHANNELS) as tmp:
            np.save(tmp, channels.sums)
    mask = object_mask(session, run, shape[1:], lambda: stack_peak(folder / "stack.npy"))
    if not mask.any():
        raise InputError(f"{session.root}: normals: the mask has no pixels")
    with atomic_path(folder / "mask.npy") as tmp:
        np.save(tmp, mask)
    try:
        lights = check_lights(run.solver_lights(mask.shape), len(run.frames), mask.shape)
    except InputError as exc:
        raise InputError(f"{session.path(LIGHTS)}: the {len(run.frames)} used lights: {exc}") from None
    solve = frame_check(folder, mask, plan_solve(run.method, lights, run.options))
    return TilePlan(str(session.root), solve, tile_context(folder, mask, solve), mask.shape,
                    pixel_tiles(mask, tile_pixels, chunk), chunk, run)


def frame_check(folder, mask, solve):
    """``solve`` with its frames' gains checked on the whole mask, as
    :func:`pipeline.photometric.estimate_normals` checks them (the memory-mapped stack as given)."""
    return check_plan_frames(solve, _stack_gatherer(folder, solve, None), np.flatnonzero(mask))


def tile_context(folder, mask, solve):
    """The method's shared context from the whole mask, gathered from the memory-mapped stack."""
    if not hasattr(solve.solver, "prepare"):
        return {}
    return prepare_context(solve.solver, _stack_gatherer(folder, solve, solve.gains), np.flatnonzero(mask),
                           solve.options)


def _stack_gatherer(folder, solve, gains):
    # a whole-object sample: read frame by frame, not through one mapping of the stack
    return gatherer(FrameByFrame(Path(folder) / "stack.npy", flat=True),
                    FrameByFrame(Path(folder) / "valid.npy", flat=True), solve.solver_lights, gains=gains)


def _registration(plan, result):
    """The serial stage's registration check on the memory-mapped stack (:func:`registration_verdict`)."""
    return registration_verdict(FrameByFrame(plan.scratch("stack.npy")),
                                FrameByFrame(plan.scratch("valid.npy")), plan.solve.solver_lights, result,
                                plan.run.align)


def run_tile(plan, tile, hook=None):
    """Solve one tile (an item of ``plan.tiles``); returns the tile file's path (str).

    Reads only the tile's rows of the memory-mapped stack. ``hook(plan, tile)``, if given, is
    called after solving and before writing (tests use it to kill the worker mid-tile). Returns
    None, solving nothing, when the plan's scratch is gone (the tiles were assembled already).
    """
    p0, r0, r1, skip, count = tile
    target = plan.scratch(f"tile-{p0:010d}.npz")
    if target.is_file():  # finished by an earlier attempt of this task
        return str(target)
    if not plan.scratch("mask.npy").is_file():
        # Dask recomputes a tile whose result was on a worker that died, also after the tail
        # assembled the tiles and removed their scratch: the tail, run again, finds the normals
        # it recorded (or solves them whole)
        return None
    stack = np.load(plan.scratch("stack.npy"), mmap_mode="r")
    valid = np.load(plan.scratch("valid.npy"), mmap_mode="r")
    mask = np.load(plan.scratch("mask.npy"), mmap_mode="r")
    k, width = stack.shape[0], stack.shape[2]
    gather = gatherer(stack[:, r0:r1].reshape(k, -1), valid[:, r0:r1].reshape(k, -1), plan.solve.solver_lights,
                      offset=r0 * width, gains=plan.solve.gains)
    local = np.flatnonzero(mask[r0:r1])[skip:skip + count]
    solve = plan.solve
    phases = phases_of(solve.solver)
    pieces, kept = [], []
    votes = {}
    # one BLAS thread: a Dask worker is one core's worth of work
    with single_threaded():
        for start in range(0, len(local), plan.chunk):
            idx = local[start:start + plan.chunk]
            picked = phases.select(*_finite(gather(idx), plan, r0, r1), context=plan.context, **solve.options)
            pieces.append(solve_chunk(phases, picked, plan.context, solve.options, solve.anchor))
            if solve.votes and "weights" in picked:
                kept.append(np.packbits(picked["weights"] > 0, axis=1))
        if solve.votes and pieces and len(kept) == len(pieces):
            votes = _tile_consensus(plan, tile, local, np.concatenate(kept), pieces, gather, phases)
    if hook is not None:
        hook(plan, tile)
    keys = tuple(key for key in CHUNK_KEYS if pieces and key in pieces[0]) + (("mismatch",) if solve.anchor else ())
    arrays = {key: np.concatenate([p[key] for p in pieces]) for key in keys} if pieces else {}
    with atomic_path(target) as tmp:
        np.savez(tmp, idx=local + r0 * width, **arrays, **votes)
    return str(target)


def _tile_consensus(plan, tile, local, bits, pieces, gather, phases):
    """The neighbour consensus of one tile (:mod:`pipeline.photometric.consensus`), in place on its
    solved ``pieces`` (one per chunk); returns the counts the tile file keeps.

    Each round's vote at a pixel reads its neighbours' decisions of the round before, so after
    R rounds of radius r the tile's pixels depend on the first-pass decisions within R r of them:
    that halo, with the tile, is voted on here, every round, as the serial stage votes on the
    whole image. Its pixels lie in the chunks before and after the tile, which are selected as
    whole chunks (the serial stage's); in each round the vetoed pixels of each chunk are selected
    (and, the tile's own, fitted) again as one chunk, as the serial stage does
    (:func:`pipeline.photometric.consensus.chunk_pieces`). The halo's outer pixels miss
    neighbours, and their votes may differ from the serial stage's, but the rounds carry a
    difference inward by r a round at most: never into the tile. The specular-peak mismatches
    stay the first pass's.
    """
    p0, r0, r1, skip, count = tile
    solve, chunk = plan.solve, plan.chunk
    reach = CONSENSUS_RADIUS * CONSENSUS_ROUNDS
    stack = np.load(plan.scratch("stack.npy"), mmap_mode="r")
    valid = np.load(plan.scratch("valid.npy"), mmap_mode="r")
    mask = np.load(plan.scratch("mask.npy"), mmap_mode="r")
    k, height, width = stack.shape
    before = np.concatenate([[0], np.cumsum(np.count_nonzero(mask, axis=1))])   # object pixels before each row
    total = int(before[-1])
    h0, h1 = max(r0 - reach, 0), min(r1 + reach, height)
    near = halo_pixels(np.asarray(mask[h0:h1]), local + (r0 - h0) * width, reach)
    order = before[h0] + np.searchsorted(np.flatnonzero(mask[h0:h1]), near)    # the halo's places in the serial order
    chunks = np.unique(order // chunk)
    # the rows of the tile and of the halo's whole chunks: one gatherer over them
    a = min(r0, int(np.searchsorted(before, chunks.min() * chunk, side="right")) - 1) if chunks.size else r0
    b = max(r1, int(np.searchsorted(before, min((chunks.max() + 1) * chunk, total) - 1, side="right"))) \
        if chunks.size else r1
    in_rows = np.flatnonzero(mask[a:b])                  # object pixels of rows [a, b), in the serial order
    start = int(before[a])
    wide = gatherer(stack[:, a:b].reshape(k, -1), valid[:, a:b].reshape(k, -1), solve.solver_lights,
                    offset=a * width, gains=solve.gains)
    own = local + (r0 - a) * width
    halo_bits = []
    halo = []
    for c in chunks:
        first, last = c * chunk, min((c + 1) * chunk, total)
        idx = in_rows[first - start:last - start]
        picked = phases.select(*_finite(wide(idx), plan, a, b), context=plan.context, **solve.options)
        halo.append(idx)
        halo_bits.append(np.packbits(picked["weights"] > 0, axis=1))
    pixels = np.concatenate([own] + halo)
    sort = np.argsort(pixels)
    pixels, decided = pixels[sort], np.concatenate([bits] + halo_bits)[sort]
    serial_order = start + np.searchsorted(in_rows, pixels)

    def refit(veto):
        vetoed = vetoed_gatherer(wide, veto)
        out, took = np.empty_like(veto.bits), np.ones(len(veto.pixels), bool)
        at = serial_order[np.searchsorted(pixels, veto.pixels)]
        for group in np.split(np.arange(len(at)), np.flatnonzero(np.diff(at // chunk)) + 1):
            idx = veto.pixels[group]
            picked = phases.select(*_finite(vetoed(idx), plan, a, b), context=plan.context, **solve.options)
            out[group] = np.packbits(picked["weights"] > 0, axis=1)
            if p0 <= at[group[0]] < p0 + count:          # the tile's own chunk: fitted again
                again = solve_chunk(phases, picked, plan.context, solve.options, False)
                piece = pieces[(int(at[group[0]]) - p0) // chunk]
                rows = at[group] - p0 - (int(at[group[0]]) - p0) // chunk * chunk
                took[group] = solved(again["status"])
                for key in CHUNK_KEYS:
                    if key in piece:
                        piece[key][rows[took[group]]] = again[key][took[group]]
            else:   # a halo chunk: only its decisions are needed, and whether the fit would take them
                took[group] = solved(phases.fit(picked, context=plan.context, **solve.options)["status"])
        return out, took

    veto = vote_rounds(decided, pixels, (b - a, width), k, refit)
    mine = (serial_order[np.searchsorted(pixels, veto.pixels)] >= p0) & \
        (serial_order[np.searchsorted(pixels, veto.pixels)] < p0 + count)
    return {"vetoed": np.int64(Veto(veto.pixels[mine], veto.bits[mine], k).observations),
            "refitted": np.int64(mine.sum())}


def _finite(gathered, plan, r0, r1):
    """``gather``'s result, refused when an observation is not finite (the serial stage checks
    the whole stack up front; a tile checks what it reads)."""
    obs = gathered[0]
    if not np.isfinite(obs).all():
        bad = int(np.argmin(np.isfinite(obs).all(axis=0)))
        raise InputError(f"{plan.root}: normals: image {bad} has non-finite pixel values "
                         f"inside the mask (rows {r0}-{r1 - 1})")
    return gathered


def assemble_normals(plan, tile_paths=None, **record):
    """Scatter the tiles into full maps, write ``normals/``, record the stage; returns the record.

    Returns :data:`WHOLE_IMAGE` instead (and writes nothing) when the tiles' specular-peak
    mismatches call for a correction of the lights. Safe to call again (Dask reruns the tail
    of a worker that died): it returns the record an earlier call made, or WHOLE_IMAGE when the
    scratch is gone without one. ``record`` goes to
    :func:`pipeline.photometric.stage.record_normals` (``timings``, ``memory``).
    """
    session = Session.open(plan.root)
    if not plan.scratch("mask.npy").is_file():  # an earlier attempt of the tail got this far
        if session.stage_is_current(STAGE, plan.params, plan.run.inputs):
            return session.stage(STAGE)
        return WHOLE_IMAGE
    mask = np.load(plan.scratch("mask.npy"))
    out, mismatch = None, []
    vetoed = refitted = 0
    for tile in plan.tiles:
        path = plan.scratch(f"tile-{tile[0]:010d}.npz")
        if not path.is_file():
            raise StageError(f"{path}: normals: tile result is missing")
        with np.load(path) as tile:
            if tile["idx"].size == 0:
                continue
            chunk = {key: tile[key] for key in CHUNK_KEYS if key in tile}
            if "vetoed" in tile:
                vetoed, refitted = vetoed + int(tile["vetoed"]), refitted + int(tile["refitted"])
            if out is None:
                out = allocate_maps(mask.shape, chunk["params"].shape[1])
            scatter_chunk(out, tile["idx"], chunk)
            if plan.anchor:
                mismatch.append(tile["mismatch"])
    options = dict(plan.solve.options, frame_check=plan.solve.gain_check)
    if plan.solve.votes:
        options["neighbour_consensus"] = consensus_record(vetoed, refitted, int(mask.sum()))
    if plan.anchor:
        verdict = first_verdict(np.concatenate(mismatch) if mismatch else np.zeros(0))
        if verdict["anchor"] == "to correct":
            shutil.rmtree(plan.scratch(), ignore_errors=True)
            return WHOLE_IMAGE
        options.update(verdict)
    shared = {key: plan.context.get(key) for key in SHARED_KEYS}
    saved = plan.scratch(CHANNELS)
    channels = ChannelSums(np.load(saved) if saved.is_file() else None)   # none saved: grey frames
    result = result_from_maps(out, mask, plan.solve.method, options, shared, lights=len(plan.solve.lights),
                              uncertain_deg=plan.solve.uncertain_deg)
    found = _registration(plan, result)
    if found.get("align"):   # frames to align and solve again: a whole-image solve, as the serial stage's
        shutil.rmtree(plan.scratch(), ignore_errors=True)
        return WHOLE_IMAGE
    prediction = predict_held_out(plan.run, FrameByFrame(plan.scratch("stack.npy")),
                                  FrameByFrame(plan.scratch("valid.npy")), plan.solve.solver_lights, result)
    record = record_normals(session, plan.run, result, channels, registration=found, prediction=prediction, **record)
    shutil.rmtree(plan.scratch(), ignore_errors=True)
    return record


def solve_tiled(session, run, memory, **options):
    """The serial normals stage when its stack exceeds the memory budget: the stack written to a
    memory-mapped scratch file, the tiles solved one after another in this process, assembled
    and recorded as the Dask path does (the same normals as a solve in memory). ``run`` is the
    stage's :class:`NormalsRun`, ``memory`` the record's ``memory`` entry, ``options`` the stage's.

    Returns the stage record, or None when the stage must run on the whole image after all (the
    specular-peak correction, :data:`WHOLE_IMAGE`); the scratch is removed either way.
    """
    started = time.perf_counter()
    plan = plan_normals(session, options, force=True, run=run, tile_pixels=SERIAL_TILE_PIXELS)
    if plan is None or plan == WHOLE_IMAGE:
        return None
    try:
        planned = time.perf_counter()
        _run_tiles(plan)
        timings = {"read": round(planned - started, 3), "solve": round(time.perf_counter() - planned, 3)}
        record = assemble_normals(plan, timings=timings, memory=memory)
    finally:
        shutil.rmtree(plan.scratch(), ignore_errors=True)
    return None if record == WHOLE_IMAGE else record


def _run_tiles(plan):
    """Every tile of ``plan``, on as many threads as frames are read with (the kernels release
    the GIL; each tile is its own file, so the assembled maps do not depend on the order)."""
    # one limit around the pool: the tiles' own single-thread contexts, entered and left by
    # several threads at once, would otherwise restore each other's limit
    with single_threaded():
        pool = ThreadPoolExecutor(read_workers(), thread_name_prefix="psrig-tile")
        try:
            for task in [pool.submit(run_tile, plan, tile) for tile in plan.tiles]:
                task.result()
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
