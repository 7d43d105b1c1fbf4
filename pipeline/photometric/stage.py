"""The ``normals`` stage: linear object frames + calibrated lights -> normal maps in ``normals/``.

Reads ``linear/<frame>.exr`` and ``linear/<frame>_sat.png`` (decode stage) and
``calibration/lights.yaml`` (calibrate stage or an importer); writes ``normals.exr``,
``normals.png``, ``mask.png``, ``albedo.exr``, ``brdf.exr``, ``residual.exr``, ``status.png``
(codes of :data:`pipeline.photometric.STATUS`), ``status_vis.png`` and ``uncertainty.exr`` (each
pixel's expected angular error, :mod:`pipeline.photometric.uncertainty`; not written when the
run cannot estimate it); records the stage.

The serial stage (:func:`normals_session`) and the tiled one (:mod:`pipeline.photometric.tiles`)
are the same three steps: :func:`begin_normals` (inputs, staleness, lights), a solve, and
:func:`record_normals` (outputs and the stage record).
"""

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import StageError
from ..core.atomic import atomic_write_text
from ..core.imageio import image_size, read_mask, read_workers, write_image, write_mask, write_normal_png
from ..core.mapped import anonymous_array
from ..core.memory import BASE_BYTES, budget_bytes, check_budget, format_gb
from ..core.lightsio import read_exclude, read_lights_yaml
from ..core.paths import EXCLUDE, LIGHTS, LIT_OBSERVATIONS, OBSERVATIONS, PREDICTION, PREDICTION_IMAGES, UNCERTAINTY
from ..core.progress import progress as progress_bar
from ..settings.normals import FOLDS, MEMORY_SHARE, EstimateOptions, NormalsOptions
from ..core.stage import Stage
from ..core.yamlio import dump_yaml, plain
from .anchor import scale_cone
from .estimate import estimate_normals
from .flags import PackedFlags
from .frame_read import read_frame, scale_into
from .object_box import crop_stack, object_box, uncrop_result
from .methods import METHODS, STATUS, STATUS_NAMES, STATUS_PALETTE, check_method_options, method_traits
from .near_depth import PASSES, refine_near_depth
from .near_lights import PointLights
from .prediction import held_out_prediction
from .registration import align_frames, alignable, check_registration
from .summary import normals_summary, normals_warnings

__all__ = ["NormalsStage", "normals_session", "registration_verdict", "begin_normals", "record_normals",
           "predict_held_out", "NormalsRun", "ChannelSums", "load_object_stack", "solve_without", "normals_memory",
           "stack_shape", "MAP_BYTES", "object_mask", "light_model", "model_record",
           "frame_gains_record", "registration_record",
           "STAGE",
           "LIGHT_MODELS", "ALIGN_MODES", "PAPER_NAMES", "STATUS_COLOURS", "SELECTION_KEYS"]

STAGE = "normals"
LIGHT_MODELS = NormalsOptions.specs()["lights_model"][1].choices
#: what the stage does with frames that do not register with the others (see :func:`normals_session`)
ALIGN_MODES = NormalsOptions.specs()["align"][1].choices
# Eq. 2's parameters with their monomials; names sort in order and avoid the bare R/G/B/A that
# EXR readers treat as colour channels.
PAPER_NAMES = ("brdf.A_x2y2", "brdf.B_x2y", "brdf.C_x2", "brdf.D_xy2", "brdf.E_xy", "brdf.F_x",
               "brdf.G_y2", "brdf.H_y", "brdf.I_1")
#: status_vis.png colour (RGB) of every uint8 status code, from the shared STATUS_PALETTE (the
#: report draws its map and legend with the same table); codes without a colour are mid grey
STATUS_COLOURS = np.full((256, 3), 128, np.uint8)
STATUS_COLOURS[list(STATUS_NAMES)] = [STATUS_PALETTE.get(STATUS_NAMES[c], (128, 128, 128)) for c in STATUS_NAMES]
#: what :mod:`pipeline.photometric.anchor` reports in the result's options, kept in the stage record
ANCHOR_KEYS = ("cone_scale", "anchor", "mismatch_deg", "highlight_pixels", "probe_mismatch_deg",
               "final_mismatch_deg", "cone_scale_range")


@dataclass
class NormalsRun:
    """One run of the normals stage on a session: what the serial and the tiled stage share.

    Attributes
    ----------
    method : str
    options : dict
        The options given to the solver (None values dropped).
    params, inputs : dict
        The stage record's parameters and input hashes.
    frames : list of dict
        The object frames used (their light not flagged), in light order.
    lights : LightSet
        The session's lights (all of them; ``frames`` say which are used).
    model : str
        'near' or 'directional' (:func:`light_model`).
    near_depth : bool
        Near lights at the depth a first solve integrates to (:mod:`pipeline.photometric.near_depth`).
    align : {'auto', 'off'}
        What the stage does with frames that do not register with the others.
    mask_rel : str or None
        The session's object mask, when it has one.
    started : float
        ``time.time()`` when the run began (the record's seconds).
    """

    method: str
    options: dict
    params: dict
    inputs: dict
    frames: list
    lights: object
    model: str
    near_depth: bool = True
    mask_rel: str = None
    started: float = field(default_factory=time.time)
    align: str = "auto"
    memory: object = None
    by_hand: dict = field(default_factory=dict)
    mask_info: dict = None

    def solver_lights(self, shape):
        """The used lights as the solver takes them: directions (K, 3) or PointLights for ``shape``."""
        chosen = [f["light"] for f in self.frames]
        if self.model == "near":
            return PointLights(self.lights.positions[chosen], shape)
        return self.lights.directions[chosen]

    def extra(self):
        """Stage-record entries of the lights used."""
        extra = {"lights_used": len(self.frames), "lights_left_out": sorted(int(k) for k in self.lights.flags),
                 "light_model": self.model}
        if self.by_hand:
            extra["lights_left_out_by_hand"] = {str(k): why for k, why in self.by_hand.items()}
        if self.mask_info:
            extra["mask"] = self.mask_info
        return extra


def _object_frames(session):
    frames = sorted(session.stage_frames("object"), key=lambda f: f["light"])
    if not frames:
        raise StageError(f"{session.root}: normals: the session has no object frames")
    lights = [f["light"] for f in frames]
    if len(set(lights)) != len(lights):
        raise StageError(f"{session.root}: normals: several object frames share a light index")
    return frames


def _inputs(session, frames, mask_rel):
    rels = [LIGHTS] + ([mask_rel] if mask_rel else []) + ([EXCLUDE] if session.path(EXCLUDE).is_file() else [])
    for frame in frames:
        for path in (session.linear_path(frame), session.saturation_path(frame)):
            if not path.is_file():
                raise StageError(f"{path}: normals: decoded frame of {frame['id']!r} is missing "
                                 "(run `psrig decode` first)")
            rels.append(session.rel(path))
    if not session.path(LIGHTS).is_file():
        raise StageError(f"{session.path(LIGHTS)}: normals: no lights (run `psrig calibrate` or import lights)")
    # the frame-to-light map is read from the manifest: editing it must rerun the stage too
    return {**session.hash_inputs(rels), **session.manifest_input(STAGE, frames, ("id", "light"))}


def light_model(lights, requested="auto"):
    """'near' or 'directional': how the normals stage uses ``lights`` (a LightSet).

    ``auto`` uses positions when lights.yaml has them and its ``light_model`` key (written by
    the calibration, which decides from the triangulation) does not say 'directional'.
    """
    if requested not in LIGHT_MODELS:
        raise StageError(f"normals: unknown light model {requested!r}; known: {', '.join(LIGHT_MODELS)}")
    if requested == "directional":
        return "directional"
    if lights.positions is None:
        if requested == "near":
            raise StageError(f"{LIGHTS}: light model 'near' asked for, but the lights have no positions")
        return "directional"
    if requested == "near" or lights.extra.get("light_model", "near") != "directional":
        return "near"
    return "directional"


def _read_stage_lights(session, frames):
    """The session's lights (flags: lights.yaml's and exclude.yaml's), the object frames whose
    light is not flagged, and {light: why} of those left out by hand (exclude.yaml)."""
    lights = read_lights_yaml(session.path(LIGHTS))
    top = max(f["light"] for f in frames)
    if top >= len(lights):
        raise StageError(f"{session.path(LIGHTS)}: {len(lights)} lights, but frame light index {top} is used")
    by_hand = read_exclude(session, len(lights))
    for index, why in by_hand.items():
        lights.flags.setdefault(index, f"left out by hand ({EXCLUDE}): {why}")
    return lights, [f for f in frames if f["light"] not in lights.flags], by_hand


def begin_normals(session, *, force=False, **options):
    """Start a normals run: its inputs, whether it is up to date, and the lights it uses.

    ``options`` are :class:`pipeline.settings.NormalsOptions` (None: the default). Returns a
    :class:`NormalsRun`, or None when the stage record still matches (and not ``force``).
    Raises StageError for missing frames or lights, InputError for an unknown option.
    """
    chosen = NormalsOptions.of(options, where=STAGE)
    check_method_options(chosen.method, chosen.solver_options())   # before any file is read
    if chosen.holdout_folds == 1:
        raise StageError("normals: --holdout-folds must be 0 (off) or at least 2, got 1")
    frames = _object_frames(session)
    mask_rel = session.manifest["lights"].get("object_mask")
    params = chosen.record()
    inputs = _inputs(session, frames, mask_rel)
    if not force and session.stage_is_current(STAGE, params, inputs):
        return None
    started = time.time()
    lights, used, by_hand = _read_stage_lights(session, frames)
    return NormalsRun(chosen.method, chosen.solver_options(), params, inputs, used, lights,
                      light_model(lights, chosen.lights_model), chosen.near_depth, mask_rel, started, chosen.align,
                      chosen.memory, by_hand)


class ChannelSums:
    """Each pixel's sum over its unsaturated observations of every colour channel (intensities
    divided out), (H, W, C) float32, gathered frame by frame while :func:`load_object_stack`
    reads the frames: the albedo's colour (:func:`_albedo_channels`) then needs no second pass
    over them (on DiLiGenT reading that pass was 0.33 s of a 2 s stage)."""

    def __init__(self, sums=None):
        self.sums, self.grey = sums, False

    def add(self, scaled, saturated):
        """Add one frame (H, W, C) with its intensities divided out; its ``saturated`` (H, W)
        pixels are zeroed in place (the frame is the caller's no longer). None: a grey frame."""
        if scaled is None or scaled.shape[2] < 2:
            self.grey = True
            return
        scaled[saturated] = 0.0
        if self.sums is None:
            self.sums = np.array(scaled)   # the reader reuses its buffer
        else:
            np.add(self.sums, scaled, out=self.sums)


def load_object_stack(session, frames, lights, channels=None, out=None, workers=None, stored=None):
    """Grey linear stack (K, H, W) float32 with intensities divided out, and valid (K, H, W): the
    unsaturated observations, a :class:`pipeline.photometric.flags.PackedFlags` (bits: an eighth
    of a bool stack) unless ``out`` gives the array to fill; ``channels`` (a :class:`ChannelSums`)
    gathers the colour sums on the way.

    The frames are read by ``workers`` threads (default :func:`read_workers`), each straight into
    its slice of the stack: a frame's only full-size temporary is the file's pixels (H, W, C),
    divided by the intensities in place and averaged over its channels into the stack. The
    channel sums are added in frame order, so every output is the same to the bit whatever the
    thread count.

    Parameters
    ----------
    out : (ndarray, ndarray), optional
        The stack (K, H, W) float32 and valid (K, H, W) bool to fill (e.g. memory-mapped
        files); default a new stack and packed flags.
    stored : callable, optional
        ``stored(index)`` once frame ``index`` is in ``out`` (a mapped file's writer gives the
        frame's pages back to the page cache there).
    """
    first = session.linear_path(frames[0])
    height, width, _ = image_size(first)
    shape = (len(frames), height, width)
    if out is None:
        images, valid = anonymous_array(shape, np.float32), PackedFlags.filled(len(frames), (height, width))
    else:
        images, valid = out
        if images.shape != shape or valid.shape != shape:
            raise StageError(f"normals: the stack to fill is {images.shape}, the frames {shape}")
    turn = threading.Condition()
    state = {"next": 0, "failed": False}
    # each thread's colour planes, free again once its frame's colours are added (in ``load``)
    buffers = threading.local()

    def load(index):
        frame = frames[index]
        path = session.linear_path(frame)
        scaled = saturated = None
        try:
            if state["failed"]:
                return
            pixels = read_frame(path)
            size, colours = pixels.shape[:2], pixels.shape[2]
            if size != (height, width):
                raise StageError(f"{path}: size {size} differs from {first}'s {(height, width)}")
            gain = lights.intensities[frame["light"]]
            gain = gain if gain.size == colours else np.full(colours, gain.mean())
            if (gain <= 0).any():
                raise StageError(f"{session.path(LIGHTS)}: light {frame['light']} has a non-positive intensity")
            # the same float32 arithmetic as read_image then ``linear / gain`` and the channel mean
            colour = channels is not None and colours > 1
            if colour and getattr(buffers, "planes", np.empty(0)).shape != (height, colours, width):
                buffers.planes = np.empty((height, colours, width), np.float32)
            scaled = scale_into(pixels, gain, images[index], colour, buffers.planes if colour else None)
            saturated = read_mask(session.saturation_path(frame))
            valid[index] = ~saturated
            if stored is not None:
                stored(index)
        except BaseException:
            state["failed"] = True
            raise
        finally:
            # float sums depend on their order: frame k's colours are added after frame k - 1's
            with turn:
                turn.wait_for(lambda: state["next"] == index or state["failed"])
                if channels is not None and not state["failed"]:
                    channels.add(scaled, saturated)
                state["next"] += 1
                turn.notify_all()

    count = min(workers or read_workers(), len(frames))
    if count == 1:
        for index in range(len(frames)):
            load(index)
    else:
        pool = ThreadPoolExecutor(count, thread_name_prefix="psrig-read")
        try:
            # submitted in frame order and taken in that order, so a task waiting for its turn
            # never waits on one that has not started
            for task in [pool.submit(load, index) for index in range(len(frames))]:
                task.result()
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
    return images, valid


#: without a mask, the object is where the brightest observation exceeds this share of the
#: object's bright level (the 99.5th percentile of the peaks)
MASK_LEVEL = 0.05
#: a mask made from brightness with more parts than this, or more of the frame than
#: MASK_MOST, is a warning (a lit background or table solved as the object)
MASK_PARTS = 10
MASK_MOST = 0.85


def object_mask(session, run, shape, peak):
    """The session's object mask (H, W) bool, checked against the frames' ``shape`` (H, W), or
    the pixels whose brightest observation (``peak()``, (H, W), called only then) exceeds
    :data:`MASK_LEVEL` of the object's bright level; where it came from, its pixels and parts
    go to ``run.mask_info`` (the record's ``mask``, :func:`mask_info`)."""
    if run.mask_rel:
        mask = read_mask(session.path(run.mask_rel))
        if mask.shape != tuple(shape):
            raise StageError(f"{session.path(run.mask_rel)}: mask size {mask.shape} differs from the frames' "
                             f"{tuple(shape)}")
        if not mask.any():   # edited after import (import refuses an empty mask)
            raise StageError(f"{session.path(run.mask_rel)}: the object mask is empty (no white pixel); "
                             "replace it by the object's mask")
        run.mask_info = mask_info(mask, run.mask_rel)
        return mask
    peak = peak()
    mask = peak > MASK_LEVEL * np.percentile(peak, 99.5)
    run.mask_info = mask_info(mask)
    return mask


def mask_info(mask, given=None):
    """Where the object mask (H, W) bool came from, its pixels and parts (8-connected), and a
    warning when one made from brightness looks like more than an object.

    Returns
    -------
    dict
        ``source`` ('given' or 'brightness'), ``file`` (given) or ``level`` (share of the
        object's level), ``pixels``, ``parts``, ``share`` (of the frame), ``text`` (the line
        printed) and, when due, ``warning``.
    """
    import cv2

    pixels = int(mask.sum())
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    parts = int(count) - 1
    largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if parts else 0
    share = pixels / mask.size
    counted = f"{pixels:,} pixels in {parts:,} part{'s' * (parts != 1)}"
    if given:
        return {"source": "given", "file": given, "pixels": pixels, "parts": parts, "share": round(share, 4),
                "text": f"mask: {given} (given at import): {counted}"}
    info = {"source": "brightness", "level": MASK_LEVEL, "pixels": pixels, "parts": parts, "share": round(share, 4),
            "text": f"mask: none given; made from brightness, {100 * MASK_LEVEL:g} % of the object's level: {counted}"}
    if parts > MASK_PARTS or share > MASK_MOST:
        info["warning"] = (f"the mask made from brightness is {parts:,} part{'s' * (parts != 1)} (the largest "
                           f"{100 * largest / max(pixels, 1):.0f} % of it) covering {100 * share:.0f} % of the "
                           "frame: it probably holds more than the object (a lit background or table, noise); "
                           "give an object mask (psrig import images ... --mask FILE)")
    return info


#: bytes per pixel of the solve's maps and the writing of normals/ (normals, parameters, albedo,
#: residual, status, counts and their file buffers), beyond the stack
MAP_BYTES = 200


def stack_shape(session, frames):
    """(K, H, W, C) of the object frames, from the first file's header."""
    height, width, channels = image_size(session.linear_path(frames[0]))
    return len(frames), height, width, channels


def normals_memory(shape, workers=1):
    """Estimated peak bytes of the normals stage on a stack of ``shape`` (K, H, W, C):
    ``in_memory`` (the stack and its saturation flags as bits, K x H x W x 4.125 bytes, the frames in flight,
    the colour sums, the maps) and ``tiled`` (the same without the stack, which is memory-mapped
    and read a tile of rows at a time)."""
    k, height, width, colours = shape
    pixels = height * width
    maps = BASE_BYTES + pixels * (MAP_BYTES + 4 * colours * (1 + 2 * workers))
    return {"in_memory": maps + (4 * k + -(-k // 8)) * pixels, "tiled": maps}


def normals_session(session, *, force=False, show_progress=True, tiled=None, **options):
    """Run the normals stage on a session; returns the stage record (None when up to date).

    ``options`` are :class:`pipeline.settings.NormalsOptions` (an unknown name is an InputError
    listing the known ones): the method and its options, which go to
    :func:`pipeline.photometric.estimate_normals`, and the stage's own. Lights flagged in
    ``lights.yaml`` are left out and listed in the record.
    ``lights_model`` is 'auto', 'directional' or 'near' (see :func:`light_model`): near lights
    give per-pixel directions and inverse-square falloff from the calibrated positions, at the
    depth a first solve's normals integrate to when ``near_depth`` (default; see
    :mod:`pipeline.photometric.near_depth`), else on the plane of the calibration spheres.
    Then every frame is registered against the normals' rendering of it
    (:func:`pipeline.photometric.registration.check_registration`); ``align`` 'auto' aligns
    the frames found moved and solves again where the object pins position well
    (:func:`pipeline.photometric.registration.alignable`), 'off' only says.
    Last, ``holdout_folds`` folds of the lights are held back in turn and the biquadratic and
    Lambertian fits scored on predicting them (:mod:`pipeline.photometric.prediction`;
    ``normals/prediction.yaml``, ``normals/prediction.exr``); 0 skips it.

    The option ``memory`` is the budget (:func:`pipeline.core.memory.budget_bytes`: None for the default share
    of the available memory, bytes or text such as '8G'). When the stack does not fit it, the
    stage solves tiles from a memory-mapped stack (:mod:`pipeline.photometric.tiles`: the same
    normals; frames found moved are named but not aligned) with ``tiled``
    (:func:`pipeline.photometric.tiles.solve_tiled`, which :func:`pipeline.photometric.normals_session`
    passes; this module does not import the tiles); when even that does not fit, or the
    run must be whole (near lights at an integrated depth), it refuses with StageError before
    reading a frame. The record's ``memory`` says which, with the estimate and the budget.
    """
    run = begin_normals(session, force=force, **options)
    if run is None:
        return None
    method, near_depth = run.method, run.near_depth
    budget = budget_bytes(run.memory, MEMORY_SHARE)
    workers = read_workers()
    needs = normals_memory(stack_shape(session, run.frames), workers)
    where = f"{session.root}: normals"
    plan = {"budget_gb": round(budget / 2 ** 30, 2), "estimate_gb": round(needs["in_memory"] / 2 ** 30, 2)}
    if needs["in_memory"] > budget:
        if run.model == "near" and run.near_depth:
            check_budget(where, needs["in_memory"], budget,
                         "near lights at the integrated depth need the whole stack: give more with --memory, "
                         "or --near-depth off to solve tiles from disk")
        if tiled is None:   # no tiled execution given: in memory or not at all
            check_budget(where, needs["in_memory"], budget, "give more with --memory")
        check_budget(where, needs["tiled"], budget, "give more with --memory, or bin the frames (psrig decode --bin 2)")
        print(f"{where}: the stack needs about {format_gb(needs['in_memory'])}, over the budget of "
              f"{format_gb(budget)}: solving tiles from a memory-mapped stack", flush=True)
        record = tiled(session, run, dict(plan, execution="tiled", estimate_gb=round(needs["tiled"] / 2 ** 30, 2)),
                       **{k: v for k, v in options.items() if k != "memory"})
        if record is not None:
            return record
        # the tiles called for a whole-image correction (the specular anchor): in memory after all
        check_budget(where, needs["in_memory"], budget, "the specular-peak correction needs the whole stack: "
                     "give more with --memory, or --specular-anchor off")
    plan["execution"] = "in memory"
    # the record's ``timings`` say where the stage's wall time went (read, solve, check, write)
    # and ``cpu`` the process's CPU seconds (every thread) of each, steadier on a shared machine
    clock = [time.perf_counter(), time.process_time()]
    timings = {"cpu": {}}

    def lap(name):
        now = time.perf_counter(), time.process_time()
        timings[name] = round(now[0] - clock[0], 3)
        timings["cpu"][name] = round(now[1] - clock[1], 3)
        clock[:] = now

    channels = ChannelSums()
    images, valid = load_object_stack(session, run.frames, run.lights, channels)
    mask = object_mask(session, run, images.shape[1:], lambda: images.max(axis=0))
    # near lights depend on where each pixel is in the frame: those solve the whole frame
    box = object_box(mask) if run.model != "near" else None
    whole_mask = mask
    if box is not None:
        images, valid = crop_stack(images, valid, box)
        mask = mask[box]
    lap("read")
    passes = PASSES if run.model == "near" and near_depth else 0
    solved_with = {}
    with progress_bar(total=int(mask.sum()) * (1 + passes), desc="normals", unit="px",
                      disable=not show_progress) as bar:
        def solve(directions, pixels):
            out = estimate_normals(images, directions, pixels, method=method, valid=valid,
                                   progress=bar.update if pixels is mask else None, **run.options)
            # the held-out check renders with the kept solve's lights (near: at its depth); by id,
            # so that the searches' solves are not all kept alive (the kept one is, so its id is
            # not reused)
            solved_with[id(out)] = directions
            return out

        lights = run.solver_lights(images.shape[1:])
        if run.model == "near":
            result, depth = refine_near_depth(solve, lights, mask, passes=passes)
        else:
            result, depth = solve(lights, mask), None
    lap("solve")
    # after the solve: every frame against the model's rendering of it (the object or camera moved?)
    result, registration, (images, valid) = _register(images, valid, lights, mask, result, method, run.options,
                                                      run.align)
    lap("registration")
    prediction = predict_held_out(run, images, valid, solved_with.get(id(result), lights), result)
    lap("prediction")
    # the stack is done with: the files' buffers are not to come on top of it
    del images, valid, lights
    if box is not None:
        result = uncrop_result(result, box, whole_mask)
    return record_normals(session, run, result, channels, near_depth=depth, registration=registration,
                          prediction=prediction, timings=timings, memory=plan)


def registration_verdict(images, valid, lights, result, align, resolve=None):
    """Every frame against the normals' rendering of it (the object or camera moved?), and what
    the stage does about it: the finding of
    :func:`pipeline.photometric.registration.check_registration`, with ``align`` True when the
    moved frames are to be aligned and the normals solved again (``align`` 'auto' and the object
    pins position well), else ``not_aligned`` saying why. Both executors decide with it."""
    found = check_registration(images, result, lights, valid, resolve=resolve)
    if found.get("moved"):
        if align == "auto" and alignable(found):
            found["align"] = True
        else:
            found["not_aligned"] = "psrig normals --align-frames off" if align != "auto" else \
                f"the object's shading pins position only to about {found['median_departure_px']:.1f} px"
    return found


def predict_held_out(run, images, valid, lights, result):
    """The held-out-light check of ``run`` (None when its ``holdout_folds`` is 0) on the stack
    (K, H, W) the result was solved from (memory-mapped is fine: a grid window is read), with
    the ``lights`` it was solved with."""
    folds = run.params.get("holdout_folds", FOLDS)
    if not folds:
        return None
    return held_out_prediction(images, valid, _fitted_lights(lights, result), result.mask, options=run.options,
                               folds=folds)


def _fitted_lights(lights, result):
    """The lights the kept solve fitted with: the specular anchor's corrected cone, when it
    corrected one (the held-out refits run without the anchor, on these lights)."""
    if result.options.get("anchor") == "corrected" and not isinstance(lights, PointLights):
        return scale_cone(np.asarray(lights, float), float(result.options["cone_scale"]))
    return lights


def _register(images, valid, lights, mask, result, method, options, align):
    """:func:`registration_verdict`, and the normals solved again with the moved frames aligned
    when it says so. Returns the result to keep, the check's finding and the (images, valid) it
    was solved from (the aligned copies when frames were aligned: the held-out check predicts
    those)."""
    def solve(stack, usable, chosen=slice(None)):
        return estimate_normals(stack, lights[chosen], mask, method=method, valid=usable, **options)

    found = registration_verdict(images, valid, lights, result, align,
                                 resolve=lambda keep: solve_without(images, valid, keep,
                                                                    lambda i, v: solve(i, v, keep)))
    if found.pop("align", False):
        images, valid = align_frames(images, valid, found["moved"])
        result = solve(images, valid)
        found["aligned"] = True
    return result, found, (images, valid)


def solve_without(images, valid, keep, solve):
    """``solve(images[keep], valid[keep])`` without a copy of the stack: the kept frames are moved
    to the front of ``images`` and ``valid`` (K, H, W) in place, in order, the others set aside,
    and every frame put back afterwards (also when ``solve`` raises).

    Parameters
    ----------
    images, valid : ndarray (K, H, W)
        float32 and bool, changed during the call and restored.
    keep : ndarray (K,) bool
    solve : callable
        ``solve(images (N, H, W), valid (N, H, W))`` on the N kept frames, contiguous views.
    """
    keep = np.asarray(keep, bool)
    kept, dropped = np.flatnonzero(keep), np.flatnonzero(~keep)
    aside = images[dropped], valid[dropped]   # copies: only the frames left out
    try:
        for index, frame in enumerate(kept):
            if index != frame:
                images[index], valid[index] = images[frame], valid[frame]
        return solve(images[:len(kept)], valid[:len(kept)])
    finally:
        # backwards: frame kept[i] >= i, so no slot is written before its frame has moved
        for index in range(len(kept) - 1, -1, -1):
            frame = kept[index]
            if index != frame:
                images[frame], valid[frame] = images[index], valid[index]
        images[dropped], valid[dropped] = aside


def record_normals(session, run, result, channels, near_depth=None, registration=None, prediction=None,
                   timings=None, memory=None):
    """Write ``normals/`` from a :class:`PhotometricResult` and record the stage; returns the record.

    ``channels`` is the :class:`ChannelSums` gathered while the frames were read (the albedo's
    colour); ``near_depth`` :func:`pipeline.photometric.near_depth.refine_near_depth`'s report,
    kept when it ran a pass; ``registration`` :func:`pipeline.photometric.registration.check_registration`'s
    finding (by frame index), kept by frame id; ``prediction``
    :func:`pipeline.photometric.prediction.held_out_prediction`'s finding (by frame index),
    written to ``normals/prediction.yaml`` (and its worst light's images to
    ``normals/prediction.exr``) and summed up in the record; ``timings`` {step: wall seconds}
    of the run so far (and ``cpu``: {step: CPU seconds}), kept with the writing's seconds added
    as ``write``; ``memory`` the budget and how the stage ran within it, kept as it is.
    """
    written = time.perf_counter(), time.process_time()
    outputs = _write_outputs(session, result, channels)
    outputs += _write_prediction(session, prediction, run.frames)
    counts = {name: int(np.sum(result.status[result.mask] == code)) for name, code in STATUS.items() if code}
    extra = {"pixels": int(result.mask.sum()), "status_counts": counts, **run.extra()}
    if near_depth is not None and near_depth["passes"]:
        extra["near_depth"] = near_depth
    extra.update(model_record(result.shared_shape, result.options.get("shape_check"), result.options))
    extra["selection"] = plain({k: result.options[k] for k in SELECTION_KEYS if k in result.options})
    extra.update(frame_gains_record(result.options.get("frame_check"), run.frames))
    if result.options.get("outline_check"):
        extra["outline_check"] = plain(result.options["outline_check"])
    extra.update(registration_record(registration, run.frames))
    extra["uncertainty"] = uncertainty_record(result.options.get("uncertainty"))
    if prediction is not None:
        extra["prediction"] = prediction_record(prediction, run.frames)
    if memory is not None:
        extra["memory"] = memory
    if timings is not None:
        extra["timings"] = {**timings, "write": round(time.perf_counter() - written[0], 3)}
        if "cpu" in timings:
            extra["timings"]["cpu"] = {**timings["cpu"], "write": round(time.process_time() - written[1], 3)}
    transfer = list(((session.stage("decode") or {}).get("transfer") or {}))
    extra["warnings"] = normals_warnings(counts, len(run.frames), result.options, extra.get("frame_gains"), transfer,
                                         registration=extra.get("registration"))
    if (run.mask_info or {}).get("warning"):
        extra["warnings"].append(run.mask_info["warning"])
    return session.record_stage(STAGE, run.params, run.inputs, outputs, seconds=time.time() - run.started,
                                **extra)


#: the channels of normals/prediction.exr, in order (prediction.captured, ...)
PREDICTION_CHANNELS = ("captured", "biquadratic", "lambert")
#: the solver's options the stage record keeps (after the policy filled them in)
SELECTION_KEYS = ("selection", "t_low", "t_shadow", "reject_k", "consensus", "scale_floor", "shape_prior",
                  "shared_shape", "selection_check", "neighbour_consensus")
def frame_gains_record(check, frames):
    """The stage record's ``frame_gains`` entry ({} without a check): the check's verdict and
    largest deviation (:mod:`pipeline.photometric.frame_gains`), the rescaled frames by id."""
    if not check:
        return {}
    check = dict(check)

    def name(index):
        return frames[int(index)]["id"]

    if "rescaled" in check:
        check["rescaled"] = {name(k): gain for k, gain in check["rescaled"].items()}
    if check.get("directions"):
        directions = dict(check["directions"])
        directions["off"] = {name(k): dict(v, **({"like": name(v["like"])} if "like" in v else {}))
                             for k, v in directions["off"].items()}
        directions["swapped"] = [[name(a), name(b)] for a, b in directions["swapped"]]
        directions["dark"] = [name(k) for k in directions.get("dark", [])]
        check["directions"] = directions
    return {"frame_gains": plain(check)}


def registration_record(found, frames):
    """The stage record's ``registration`` entry ({} without a check): the moved frames by id."""
    if not found:
        return {}
    found = dict(found)
    if found.get("moved"):
        found["moved"] = {frames[int(k)]["id"]: shift for k, shift in found["moved"].items()}
    if found.get("run_from") is not None:
        found["run_from"] = frames[int(found["run_from"])]["id"]
    return {"registration": plain(found)}


def prediction_record(found, frames):
    """The stage record's ``prediction`` entry: verdict, overall errors and the worst light (by
    frame id); the per-light table is in ``normals/prediction.yaml``."""
    # no time: the serial and the tiled stage write the same bytes (the stage's seconds cover it)
    keep = {k: v for k, v in found.items() if k not in ("lights", "images", "seconds")}
    if "worst_light" in keep:
        keep["worst_light"] = frames[int(keep["worst_light"])]["id"]
        worst = found["lights"][int(found["worst_light"])]
        keep["worst_light_pct"] = {k: worst[k] for k in ("biquadratic_pct", "lambert_pct")}
    return plain(keep)


def _write_prediction(session, found, frames):
    """normals/prediction.yaml (every light by frame id) and prediction.exr (the worst light's
    captured and predicted images on the sample grid); the files' names ([] when none)."""
    if found is None:
        # not checked this run (--holdout-folds 0, the tiled stage): an earlier run's files are
        # not of this fit
        for rel in (PREDICTION, PREDICTION_IMAGES):
            if session.path(rel).is_file():
                session.path(rel).unlink()
        return []
    table = {k: v for k, v in found.items() if k != "seconds"}
    images = table.pop("images", None)
    if "lights" in table:
        table["lights"] = [dict(entry, frame=frames[entry["light"]]["id"], light=int(frames[entry["light"]]["light"]))
                           for entry in table["lights"]]
        table["worst_light"] = frames[int(table["worst_light"])]["id"]
    atomic_write_text(session.path(PREDICTION), dump_yaml(plain(table)))
    written = [PREDICTION]
    if images:
        stack = np.stack([images[k] for k in PREDICTION_CHANNELS], axis=2).astype(np.float32)
        write_image(session.path(PREDICTION_IMAGES), stack,
                    channel_names=tuple(f"prediction.{k}" for k in PREDICTION_CHANNELS))
        written.append(PREDICTION_IMAGES)
    elif session.path(PREDICTION_IMAGES).is_file():
        session.path(PREDICTION_IMAGES).unlink()   # an earlier run's: not of this fit
    return written


def _write_outputs(session, result, channels):
    """Write the maps of ``normals/`` (on the reading threads: each file's encoding releases the
    GIL, and at 4 MP the eleven files took 2.6 s one after another); their names in order."""
    mask = result.mask
    lit = result.used if result.lit is None else result.lit
    channel_names = PAPER_NAMES if result.params.shape[2] == 9 else None
    # normals.exr names its channels for what they hold (camera frame: x right, y up, z toward
    # the camera) rather than R, G, B; readers take them in this order
    files = {
        "normals/normals.exr": lambda path: write_image(path, result.normals.astype(np.float32),
                                                        channel_names=("normal.x", "normal.y", "normal.z")),
        "normals/albedo.exr": lambda path: write_image(path, _albedo_channels(result, channels).astype(np.float32)),
        "normals/residual.exr": lambda path: write_image(path, result.residual.astype(np.float32)),
        "normals/brdf.exr": lambda path: write_image(path, result.params, channel_names=channel_names),
        "normals/normals.png": lambda path: write_normal_png(path, result.normals, mask & (result.status != 0)),
        "normals/mask.png": lambda path: write_mask(path, mask),
        "normals/status.png": lambda path: write_image(path, result.status, bits=8),
        "normals/status_vis.png": lambda path: write_image(path, STATUS_COLOURS[result.status], bits=8),
        OBSERVATIONS: lambda path: write_image(path, np.where(mask, result.used, 0).astype(np.uint16), bits=16),
        LIT_OBSERVATIONS: lambda path: write_image(path, np.where(mask, lit, 0).astype(np.uint16), bits=16),
    }
    if result.uncertainty is None:
        # a map from an earlier run would pass for this one's
        session.path(UNCERTAINTY).unlink(missing_ok=True)
    else:
        files[UNCERTAINTY] = lambda path: write_image(path, np.where(mask, result.uncertainty, np.nan).astype(
            np.float32), channel_names=("uncertainty",))
    with ThreadPoolExecutor(read_workers(), thread_name_prefix="psrig-write") as pool:
        for task in [pool.submit(write, session.path(rel)) for rel, write in files.items()]:
            task.result()
    return list(files)


def uncertainty_record(found):
    """The stage record's ``uncertainty``: the shares of the pixels expected within 5 degrees and
    over the threshold, the threshold and the median (rounded), or ``not_estimated`` with why."""
    if found is None or isinstance(found, str):
        return {"not_estimated": found or "the method gave no uncertainty"}
    return {key: round(float(value), 4) if isinstance(value, float) else value for key, value in found.items()}


def _albedo_channels(result, channels):
    """The albedo (H, W) grey, or (H, W, C) when the object frames have C > 1 colour channels:
    the grey albedo times each pixel's channel ratio, sum_k I_kc / sum_k mean_c I_kc over its
    unsaturated observations (intensities divided out, as the solve saw them).

    The ratio of sums weights each observation by its brightness, so shadowed observations,
    all noise, barely count; its channel mean is 1, so the channels average to the grey albedo.
    The sums come from ``channels`` (:class:`ChannelSums`), gathered as the frames were read:
    memory stays (H, W, C) whatever the light count.
    """
    sums = channels.sums
    if channels.grey or sums is None or sums.shape[:2] != result.albedo.shape:
        return result.albedo
    grey = sums.mean(axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(grey > 0, sums / grey, 1.0)
    return result.albedo[:, :, None] * ratio


def model_record(shared_shape, shape_check, anchor):
    """Stage-record entries of the fit: the shared shape, its single-material check and the
    specular anchor's outcome (the keys of :data:`ANCHOR_KEYS` found in ``anchor``), each only
    when present."""
    extra = {}
    if shared_shape is not None:
        extra["shared_shape"] = [round(float(v), 6) for v in shared_shape]
    if shape_check is not None:
        extra["shared_shape_check"] = plain(shape_check)
    found = {k: anchor[k] for k in ANCHOR_KEYS if k in (anchor or {})}
    if found:
        extra["specular_anchor"] = plain(found)
    return extra


class NormalsStage(Stage):
    """The ``normals`` stage (:class:`pipeline.core.stage.Stage`): :func:`normals_session`, with
    ``tiled`` its execution in tiles for a stack over the memory budget
    (:func:`pipeline.photometric.tiles.solve_tiled`; the package puts the two together, as the
    tiles import this module)."""

    name = STAGE
    Options = NormalsOptions
    reads = ("linear/<frame>.exr and <frame>_sat.png of the object frames", LIGHTS,
             "the object mask the manifest names", "session.yaml: each object frame's id and light")

    def __init__(self, tiled=None):
        self.tiled = tiled

    def work(self, session, options, *, force, jobs):
        if not session.path(LIGHTS).is_file():
            raise StageError(f"{session.path(LIGHTS)}: missing; the calibrate stage makes it")
        record = normals_session(session, force=force, tiled=self.tiled, **options)   # warnings: in its record
        return record is not None, normals_summary(record) if record is not None else ""

    def merge(self, recorded, given):
        """Recorded options replaced by ``given``; when ``given`` changes the method, the recorded
        options the new method does not take are dropped (they were the old method's)."""
        if given.get("method", recorded.get("method")) == recorded.get("method") or given["method"] not in METHODS:
            return {**recorded, **given}   # (an unknown method is refused, with the known ones, by the stage)
        takes = set(method_traits(METHODS[given["method"]]).options.specs()) | set(NormalsOptions.STAGE_FIELDS) \
            | set(EstimateOptions.specs())
        return {**{k: v for k, v in recorded.items() if k in takes}, **given}

