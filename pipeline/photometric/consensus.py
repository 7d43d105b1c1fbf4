"""Neighbour consensus of the selection's per-light decisions.

The robust selection (:func:`pipeline.photometric.selection.select_robust`) decides, pixel by
pixel, which of its observations to keep. Those decisions are spatially coherent: a cast
shadow, a highlight or an interreflection covers a patch of the surface under one light, not a
pixel. A pixel that keeps an observation most of its object neighbours rejected has usually
kept an outlier its own residuals could not expose (a fit pulled toward it). So after the first
pass, for a (2 r + 1) x (2 r + 1) window (:data:`pipeline.settings.normals.CONSENSUS_RADIUS`):
an observation (pixel p, light k) that p kept is vetoed when more than
:data:`pipeline.settings.normals.CONSENSUS_SHARE` of p's object neighbours (those in the
window, p excluded; at least :data:`pipeline.settings.normals.CONSENSUS_MIN_NEIGHBOURS` of them)
did not keep light k. The pixels with a vetoed observation are then selected and fitted again
without it (the veto removes it from the usable observations, as a saturated one is, so the
robust selection runs again on the rest); the others keep their first-pass result. The vote is
taken :data:`pipeline.settings.normals.CONSENSUS_ROUNDS` times, each on the decisions the last
round left (:func:`vote_rounds`).

The vote reads each pixel's own decisions and its neighbours', and nothing else: the serial
stage votes over the whole image (:func:`refine_run`), a tile over its pixels and a halo of
neighbours around them (:func:`halo_pixels`, rounds x radius wide), and both refit the same
pixels with the same veto, so their normals are identical. Everything is vectorised: box sums
over the (H, W) decisions of one light at a time.
"""

from typing import NamedTuple

import numpy as np

from ..settings.normals import CONSENSUS_MIN_NEIGHBOURS, CONSENSUS_RADIUS, CONSENSUS_ROUNDS, CONSENSUS_SHARE
from .engine import NO_NORMAL, KeptSelection, run_chunks

__all__ = ["Veto", "box_sums", "consensus_veto", "halo_pixels", "vetoed_gatherer", "refine_run",
           "consensus_record", "chunk_pieces", "vote_rounds", "solved", "CONSENSUS_ROUNDS", "CONSENSUS_RADIUS", "CONSENSUS_SHARE", "CONSENSUS_MIN_NEIGHBOURS"]


class Veto(NamedTuple):
    """The observations the neighbours' vote removes.

    Attributes
    ----------
    pixels : ndarray (A,) int
        Flat indices (ascending) of the pixels with at least one vetoed observation.
    bits : ndarray (A, ceil(K / 8)) uint8
        Their vetoed observations, packed eight to a byte (``np.packbits`` along the lights).
    count : int
        Observations per pixel (K).
    """

    pixels: np.ndarray
    bits: np.ndarray
    count: int

    def get(self, idx):
        """The vetoed observations (n, K) bool of flat pixels ``idx`` (n,), which must be among ``pixels``."""
        return np.unpackbits(self.bits[np.searchsorted(self.pixels, idx)], axis=1, count=self.count).astype(bool)

    @property
    def observations(self):
        """How many observations the vote removed."""
        return int(np.unpackbits(self.bits, axis=1).sum()) if self.bits.size else 0


def box_sums(stack, radius):
    """Sums over every (2 r + 1) x (2 r + 1) window, zero outside: (L, H, W) of 0/1 (L, H, W).

    Shifted adds, separable (rows, then columns), in the smallest unsigned integer that holds
    (2 r + 1)^2: exact counts (a float filter's rounding could tip a vote), and a few bytes per
    pixel of the image, whatever its size.
    """
    size = 2 * radius + 1
    kind = np.uint8 if size * size <= 255 else np.uint16
    stack = np.asarray(stack, kind)
    rows = np.zeros(stack.shape, kind)
    width, height = stack.shape[2], stack.shape[1]
    for d in range(-radius, radius + 1):
        rows[:, :, max(0, -d):width - max(0, d)] += stack[:, :, max(0, d):width - max(0, -d)]
    out = np.zeros(stack.shape, kind)
    for d in range(-radius, radius + 1):
        out[:, max(0, -d):height - max(0, d)] += rows[:, max(0, d):height - max(0, -d)]
    return out


def consensus_veto(bits, pixels, shape, count, radius=CONSENSUS_RADIUS, share=CONSENSUS_SHARE,
                   min_neighbours=CONSENSUS_MIN_NEIGHBOURS):
    """The neighbours' vote on the kept observations of ``pixels``.

    Parameters
    ----------
    bits : ndarray (P, ceil(K / 8)) uint8
        Each pixel's kept observations, packed (:class:`pipeline.photometric.engine.KeptSelection`).
    pixels : ndarray (P,) int
        Their flat indices in an image of ``shape`` (H, W), ascending; the object pixels the
        vote counts as neighbours are these.
    count : int
        Observations per pixel (K).
    radius, share, min_neighbours
        The window's radius (1: 3 x 3), the share of the neighbours that must have rejected a
        light (strictly more), and the neighbours a pixel needs for its vote to count.

    Returns
    -------
    Veto
        The pixels with a vetoed observation and those observations.
    """
    pixels = np.asarray(pixels)
    if pixels.size == 0:
        return Veto(pixels, bits[:0], count)
    rows, cols = np.unravel_index(pixels, shape)
    top, left = rows.min(), cols.min()
    rows, cols = rows - top, cols - left
    frame = (int(rows.max()) + 1, int(cols.max()) + 1)
    plane = np.zeros((1,) + frame, np.uint8)
    plane[0, rows, cols] = 1
    neighbours = box_sums(plane, radius)[0, rows, cols].astype(np.int64) - 1
    voting = neighbours >= min_neighbours
    limit = share * neighbours
    out = np.zeros_like(bits)
    # one light at a time: a few bytes per pixel of the image, whatever the number of lights
    for byte in range(bits.shape[1]):
        kept = np.unpackbits(bits[:, byte:byte + 1], axis=1)                       # (P, 8)
        veto = np.zeros(kept.shape, bool)
        for j in range(min(8, count - 8 * byte)):
            plane[0, rows, cols] = kept[:, j]
            keepers = box_sums(plane, radius)[0, rows, cols].astype(np.int64) - kept[:, j]   # p excluded
            veto[:, j] = (kept[:, j] > 0) & voting & (neighbours - keepers > limit)
        out[:, byte] = np.packbits(veto, axis=1)[:, 0]
    hit = out.any(axis=1)
    return Veto(pixels[hit], out[hit], count)


def halo_pixels(mask, own, radius=CONSENSUS_RADIUS):
    """The object pixels within ``radius`` (Chebyshev) of ``own`` but not among them.

    Parameters
    ----------
    mask : ndarray (H, W) bool
        The object (a window of it).
    own : ndarray (n,) int
        Flat indices of a tile's pixels in ``mask``.

    Returns
    -------
    ndarray (m,) int
        Flat indices of the halo, ascending: the neighbours whose decisions the tile's vote reads.
    """
    tile = np.zeros((1,) + mask.shape, np.uint8)
    tile.reshape(-1)[own] = 1
    near = (box_sums(tile, radius)[0] > 0) & mask
    near.reshape(-1)[own] = False
    return np.flatnonzero(near)


def vetoed_gatherer(gather, veto):
    """``gather`` with the vetoed observations of ``veto``'s pixels marked unusable (as saturated ones are)."""

    def vetoed(idx):
        obs, valid, lights = gather(idx)
        usable = ~veto.get(idx)
        return obs, usable if valid is None else valid & usable, lights

    return vetoed


def chunk_pieces(pixels, chunk, subset):
    """``subset`` (ascending, among ``pixels``) cut where ``pixels`` is cut into chunks of
    ``chunk``: the pixels of each first-pass chunk that are solved again, as one chunk. So a pixel
    is refitted beside the same pixels in the serial stage and in a tile (whose chunks are the
    serial stage's), and gets the same last bits."""
    order = np.searchsorted(pixels, subset) // chunk
    cuts = np.flatnonzero(np.diff(order)) + 1
    return [part for part in np.split(subset, cuts) if part.size]


def vote_rounds(bits, pixels, shape, count, refit, rounds=None):
    """The neighbours' vote, ``rounds`` times (:data:`pipeline.settings.normals.CONSENSUS_ROUNDS`).

    Each round votes on the current decisions (:func:`consensus_veto`); the pixels with a vetoed
    observation are selected again without every observation vetoed at them so far, and their new
    decisions are the next round's. A pixel no round vetoes keeps its first-pass result; one whose
    refit determines no normal keeps its last result and takes no further part (the vote must not
    take a pixel's normal away: its observations left too few, or too close to coplanar).

    Parameters
    ----------
    bits : ndarray (P, ceil(K / 8)) uint8
        The first-pass decisions of ``pixels`` (flat, ascending, in an image of ``shape``).
    count : int
        Observations per pixel (K).
    refit : callable
        ``refit(veto)`` selects (and fits) ``veto.pixels`` again without ``veto``'s observations and
        returns their new decisions (A, ceil(K / 8)) uint8 and which of them it took (A,) bool (a
        normal found: :func:`solved`); it keeps the results of those only.

    Returns
    -------
    Veto
        Every pixel refitted, with all the observations vetoed at it.
    """
    rounds = CONSENSUS_ROUNDS if rounds is None else rounds
    bits = bits.copy()
    vetoed = np.zeros_like(bits)
    touched, frozen = np.zeros(len(pixels), bool), np.zeros(len(pixels), bool)
    for _ in range(rounds):
        veto = consensus_veto(bits, pixels, shape, count, CONSENSUS_RADIUS, CONSENSUS_SHARE, CONSENSUS_MIN_NEIGHBOURS)
        rows = np.searchsorted(pixels, veto.pixels)
        live = ~frozen[rows]
        rows = rows[live]
        if rows.size == 0:
            break
        trial = vetoed[rows] | veto.bits[live]
        new, took = refit(Veto(pixels[rows], trial, count))
        vetoed[rows[took]], bits[rows[took]] = trial[took], new[took]
        touched[rows[took]] = True
        frozen[rows[~took]] = True
    return Veto(pixels[touched], vetoed[touched], count)


def solved(status):
    """Whether pixels with these status codes (n,) have a normal."""
    return ~np.isin(status, NO_NORMAL)


def refine_run(solver, gather, kept, maps, options, context, *, chunk_size, workers=None):
    """The consensus rounds of a serial run (:func:`vote_rounds`) over ``kept`` (a complete
    :class:`pipeline.photometric.engine.KeptSelection` of the run's pixels): the vetoed pixels are
    selected and fitted again with the run's ``context``, each first-pass chunk's vetoed pixels as
    one chunk (:func:`chunk_pieces`), and the refits taken are written into the run's ``maps``
    (:func:`pipeline.photometric.engine.allocate_maps`' maps, (H, W, ...)) in place. The refits
    are solved in maps of their own pixels only (a (1, A) image), not of the whole image.
    Returns the :class:`Veto` of the pixels refitted."""
    shape = maps["status"].shape

    def refit(veto):
        place = np.arange(len(veto.pixels))
        new = KeptSelection(place, veto.count)
        vetoed = vetoed_gatherer(gather, veto)
        pieces = [np.searchsorted(veto.pixels, part) for part in chunk_pieces(kept.pixels, chunk_size, veto.pixels)]
        again = run_chunks(solver, lambda idx: vetoed(veto.pixels[idx]), place, (1, len(place)), options,
                           chunk_size=chunk_size, workers=workers, context=context, keep=new, pieces=pieces)
        took = solved(again.maps["status"][0])
        for key, values in maps.items():
            flat = values.reshape((-1,) + values.shape[2:])
            flat[veto.pixels[took]] = again.maps[key][0][took]
        return new.bits, took

    return vote_rounds(kept.bits, kept.pixels, shape, kept.count, refit)


def consensus_record(observations, refitted, pixels):
    """What the result's options (and the stage record's ``selection``) say of the vote: the
    ``observations`` it removed and the pixels ``refitted``, of ``pixels`` object pixels."""
    return {"radius": CONSENSUS_RADIUS, "share": CONSENSUS_SHARE, "rounds": CONSENSUS_ROUNDS,
            "observations_vetoed": int(observations),
            "pixels_refitted": int(refitted), "of_pixels": int(pixels)}
