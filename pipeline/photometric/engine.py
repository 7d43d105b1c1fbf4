"""The chunk engine: one estimation of an image, chunk by chunk, on all cores.

Every path that solves photometric stereo goes through these functions: the in-memory
:func:`pipeline.photometric.estimate_normals` (all chunks here, :func:`run_chunks`) and the
tiled stage of :mod:`pipeline.photometric.tiles` (a tile's chunks on a Dask worker, with
:func:`solve_chunk`, scattered by :func:`scatter_chunk` into :func:`allocate_maps`). So a
chunk holds the same pixels and gets the same arithmetic whichever path runs it.

A method (:mod:`pipeline.photometric.methods`) may prepare a shared context once per image
(:func:`prepare_context`; the biquadratic shared shape) and may split a chunk into a
``select`` phase, which never waits for that context, and a ``fit`` phase, which does. While
one worker prepares the context, the others select chunks ahead (up to
:data:`LOOKAHEAD_BYTES`). Chunks run on one thread per core with one BLAS thread each. The
default chunk (2048 pixels) keeps a chunk's (N, K) arrays near the cores' caches: measured
faster than 8192.
"""

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from ..core.jit import single_threaded
from .anchor import highlight_mismatch
from .flags import flag_columns
from .lambert import normal_leverage
from .methods import STATUS
from .near_lights import PointLights, observations_at

__all__ = ["Context", "ChunkRun", "OnePhase", "KeptSelection", "phases_of", "gatherer", "prepare_context",
           "solve_chunk", "normal_leverage", "allocate_maps", "scatter_chunk", "run_chunks", "LOOKAHEAD_BYTES", "CHUNK_SIZE", "SHARED_KEYS",
           "CHUNK_KEYS", "NO_NORMAL"]

#: statuses without a normal (zero in the maps)
NO_NORMAL = (STATUS["too_few"], STATUS["shadowed"], STATUS["ill_posed"])
#: what a method's context reports in the result: the shared shape and its check
SHARED_KEYS = ("shape_paper", "shape_check")
#: what a solved chunk holds, per pixel (a method without "lit" counts its used observations)
CHUNK_KEYS = ("b", "status", "used", "lit", "rss", "params", "leverage")
#: Pixels per chunk (memory per chunk is about CHUNK_SIZE x K x 200 bytes)
CHUNK_SIZE = 2048
#: Bytes of observations (float64) a worker holds selected ahead while the shared context is
#: prepared; the selection's weights make about three times that. 32 MiB is 20 chunks of 2048
#: pixels x 96 lights: enough to keep the cores busy while the context is fitted.
LOOKAHEAD_BYTES = 32 * 2**20


class ChunkRun(NamedTuple):
    """What :func:`run_chunks` returns.

    Attributes
    ----------
    maps : dict
        :func:`allocate_maps`' maps, filled.
    shared : dict
        The :data:`SHARED_KEYS` of the method's context (None when absent).
    mismatch : ndarray (M,)
        The specular-peak mismatches (empty without ``anchor``).
    peaks : ndarray (P,) int
        Flat indices of the pixels that show a specular peak (empty without ``anchor``).
    context : dict
        The method's whole context (``run_chunks(..., context=)`` solves more pixels with it).
    """

    maps: dict
    shared: dict
    mismatch: np.ndarray
    peaks: np.ndarray
    context: dict


class OnePhase:
    """A method with no selection phase of its own, run whole in :meth:`fit`."""

    def __init__(self, solver):
        self.solver = solver

    def select(self, obs, valid, lights, context=None, **_):
        return {"obs": obs, "valid": valid, "lights": lights}

    def fit(self, picked, context=None, **options):
        return self.solver(picked["obs"], picked["valid"], picked["lights"], context=context, **options)


class KeptSelection:
    """The observations a run selected at each of its pixels, for later runs to reuse.

    Packed eight to a byte: (P, ceil(K / 8)) bytes, 1/32 of a float32 stack. Chunks put their
    rows from any worker (each chunk its own rows).

    Parameters
    ----------
    pixels : ndarray (P,) int
        Flat indices of the run's pixels, ascending.
    count : int
        Observations per pixel (K).
    """

    def __init__(self, pixels, count):
        self.pixels, self.count = pixels, count
        self.bits = np.zeros((len(pixels), (count + 7) // 8), np.uint8)
        self._filled = np.zeros(len(pixels), bool)

    def put(self, idx, weights):
        """Keep ``weights`` (n, K) > 0 for flat pixels ``idx`` (n,)."""
        rows = np.searchsorted(self.pixels, idx)
        self.bits[rows] = np.packbits(weights > 0, axis=1)
        self._filled[rows] = True

    def complete(self):
        """Whether every pixel has been put (a method without a selection phase puts none)."""
        return bool(self._filled.all())

    def get(self, idx):
        """The kept selection (n, K) bool of flat pixels ``idx`` (n,), which must be among ``pixels``."""
        return np.unpackbits(self.bits[np.searchsorted(self.pixels, idx)], axis=1, count=self.count).astype(bool)


def phases_of(solver):
    """``solver`` as an object with ``select`` and ``fit`` phases."""
    return solver if hasattr(solver, "select") else OnePhase(solver)


class Context:
    """A method's prepared context (a dict), computed in the background; ``get`` waits for it."""

    def __init__(self, future):
        self._future = future

    def ready(self):
        return self._future is None or self._future.done()

    def get(self, key, default=None):
        return default if self._future is None else self._future.result().get(key, default)

    def get_all(self):
        """The whole context dict (waits for it)."""
        return {} if self._future is None else self._future.result()


def gatherer(flat_images, flat_valid, lights, offset=0, gains=None):
    """A function ``gather(idx)`` returning the solver's view of pixels ``idx``.

    Parameters
    ----------
    flat_images : ndarray (K, P)
        Observations, any float dtype (memory-mapped is fine: only ``idx`` is read).
    flat_valid : ndarray (K, P) bool, PackedFlags (K, H, W) or None
    lights : ndarray (K, 3) or (K, H, W, 3), or PointLights
    offset : int
        Index in the whole image of ``flat_images``' first pixel (a tile's first row).
    gains : ndarray (K,), optional
        Each frame's gain (:mod:`pipeline.photometric.frame_gains`): observations are divided by it.

    Returns
    -------
    callable
        ``gather(idx) -> (obs (N, K) float64, valid (N, K) or None, lights (K, 3) or (N, K, 3))``.
    """
    k = flat_images.shape[0]
    flat_lights = None if isinstance(lights, PointLights) or lights.ndim == 2 else lights.reshape(k, -1, 3)

    def gather(idx):
        obs = flat_images[:, idx].T.astype(np.float64)
        if gains is not None:
            obs /= gains
        obs_valid = None if flat_valid is None else flag_columns(flat_valid, idx).T
        if flat_lights is not None:
            return obs, obs_valid, np.ascontiguousarray(flat_lights[:, idx + offset].transpose(1, 0, 2))
        obs, obs_lights = observations_at(lights, obs, idx + offset)
        return obs, obs_valid, obs_lights

    return gather


def prepare_context(solver, gather, pixels, options):
    """The method's shared context fitted on ``pixels`` (flat indices), {} when it has none."""
    return solver.prepare(gather, pixels, **options) if hasattr(solver, "prepare") else {}


def solve_chunk(phases, picked, context, options, anchor):
    """The fit of one selected chunk; with ``anchor``, also its specular-peak mismatches.

    ``picked`` is what ``phases.select`` returned. The mismatches (``chunk["mismatch"]``,
    :func:`pipeline.photometric.anchor.highlight_mismatch`; ``chunk["peaks"]`` the chunk's rows
    that show a peak) are measured here, on the chunk's observations already in memory.
    """
    chunk = phases.fit(picked, context=context, **options)
    chunk["leverage"] = normal_leverage(chunk["b"], picked.get("weights", picked.get("valid")), picked["lights"])
    if anchor:
        chunk["mismatch"], chunk["peaks"] = highlight_mismatch(picked["obs"], np.nan_to_num(chunk["b"]),
                                                               picked["lights"], valid=picked["valid"], rows=True)
    return chunk


def allocate_maps(shape, n_params):
    """Zeroed result maps for an (H, W) image and methods with ``n_params`` parameters."""
    h, w = shape
    return {"normals": np.zeros((h, w, 3), np.float32), "status": np.zeros((h, w), np.uint8),
            "albedo": np.zeros((h, w), np.float32), "params": np.zeros((h, w, n_params), np.float32),
            "residual": np.zeros((h, w), np.float32), "used": np.zeros((h, w), np.uint16),
            "lit": np.zeros((h, w), np.uint16), "leverage": np.full((h, w), np.nan, np.float32)}


def scatter_chunk(maps, idx, chunk):
    """Write a solved chunk (flat pixel indices ``idx``) into :func:`allocate_maps`' maps."""
    rows, cols = np.unravel_index(idx, maps["status"].shape)
    b = chunk["b"]
    albedo = np.linalg.norm(b, axis=1)
    ok = np.isfinite(b).all(axis=1) & (albedo > 0) & ~np.isin(chunk["status"], NO_NORMAL)
    normals = np.where(ok[:, None], b / np.where(ok, albedo, 1.0)[:, None], 0.0)
    maps["normals"][rows, cols] = normals
    maps["albedo"][rows, cols] = np.where(ok, albedo, 0.0)
    maps["status"][rows, cols] = chunk["status"]
    maps["params"][rows, cols] = np.where(ok[:, None], np.nan_to_num(chunk["params"]), 0.0)
    used = np.maximum(chunk["used"], 1)
    rms = np.sqrt(np.maximum(chunk["rss"], 0) / used) / np.where(ok, albedo, 1.0)
    maps["residual"][rows, cols] = np.where(ok, np.nan_to_num(rms), 0.0)
    maps["used"][rows, cols] = chunk["used"]
    maps["lit"][rows, cols] = chunk["lit"] if "lit" in chunk else chunk["used"]
    if "leverage" in chunk:
        maps["leverage"][rows, cols] = np.where(ok, chunk["leverage"], np.nan)


def run_chunks(solver, gather, pixels, shape, options, *, anchor=False, chunk_size=CHUNK_SIZE, workers=None,
               progress=None, context=None, keep=None, reuse=None, pieces=None):
    """One estimation over every chunk of ``pixels``.

    Parameters
    ----------
    solver
        A method of :data:`pipeline.photometric.methods.METHODS`.
    gather : callable
        :func:`gatherer`'s function for the image.
    pixels : ndarray (P,) int
        Flat indices of the pixels to solve, in row-major order.
    shape : (H, W)
    options : dict
        The method's options (after :func:`pipeline.photometric.selection.resolve_selection`).
    anchor : bool
        Also measure the specular-peak mismatches.
    chunk_size, workers, progress
        Pixels per chunk; threads (default: the cores); ``progress(n)`` after each chunk.
    context : dict, optional
        The method's shared context, when it is known already (not prepared again).
    keep, reuse : KeptSelection, optional
        Where to keep each chunk's selected observations; a complete one whose selection the
        chunks (and the context's preparation) take instead of selecting again.
    pieces : list of ndarray (n,) int, optional
        The chunks themselves (their union ``pixels``), instead of ``pixels`` cut every
        ``chunk_size``.

    Returns
    -------
    ChunkRun
    """
    out = {}
    mismatch, peaks = [], []
    lock = threading.Lock()
    if pieces is None:
        pieces = [pixels[i:i + chunk_size] for i in range(0, len(pixels), chunk_size)]
    chunks = iter(pieces)
    phases = phases_of(solver)
    chosen = (lambda idx: {"chosen": reuse.get(idx)}) if reuse is not None else (lambda idx: {})

    def finish(idx, picked):
        chunk = solve_chunk(phases, picked, context, options, anchor)
        with lock:
            if not out:
                out.update(allocate_maps(shape, chunk["params"].shape[1]))
            scatter_chunk(out, idx, chunk)
            if anchor:
                mismatch.append(chunk["mismatch"])
                peaks.append(idx[chunk["peaks"]])
        if progress:
            progress(len(idx))

    def work():
        # Chunks are selected ahead while the shared context is being prepared (selection
        # never waits for it), up to LOOKAHEAD_BYTES of them, then fitted; one worker per core.
        held = []
        while True:
            with lock:
                idx = next(chunks, None)
            if idx is None:
                break
            picked = phases.select(*gather(idx), context=context, **chosen(idx), **options)
            if keep is not None and "weights" in picked:
                keep.put(idx, picked["weights"])
            held.append((idx, picked))
            if context.ready() or sum(p["obs"].nbytes for _, p in held) >= LOOKAHEAD_BYTES:
                for item in held:
                    finish(*item)
                held.clear()
        for item in held:
            finish(*item)

    # numpy releases the GIL in its array loops, so chunks overlap on several cores.
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(pieces)))
    # One BLAS thread per worker, even with one worker: the products here are thin
    # ((N, K) @ (K, <= 9)), so BLAS threads only spin and oversubscribe the cores.
    with single_threaded(), ThreadPoolExecutor(n_workers) as pool:
        # Submitted first, so a worker takes it before any chunk; the other workers select
        # chunks meanwhile.
        if context is None:
            reused = {} if reuse is None else {"chosen": reuse.get}
            context = Context(pool.submit(solver.prepare, gather, pixels, **reused, **options)
                              if hasattr(solver, "prepare") else None)
        else:
            context = Context(pool.submit(dict, context))
        for future in [pool.submit(work) for _ in range(n_workers)]:
            future.result()
    return ChunkRun(out, {key: context.get(key) for key in SHARED_KEYS},
                    np.concatenate(mismatch) if mismatch else np.zeros(0),
                    np.concatenate(peaks) if peaks else np.zeros(0, np.int64), context.get_all())
