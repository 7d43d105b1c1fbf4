"""Options of the photometric-stereo methods and of the ``normals`` stage.

A method's options are the :class:`SelectionOptions` (which observations each pixel's fit
uses; every method's frame checks use them too) and its own (:class:`BiquadraticOptions`,
:class:`AlternationOptions`); :class:`EstimateOptions` are :func:`pipeline.photometric.estimate_normals`'
for every method. :class:`NormalsOptions` adds what the stage decides (the method, the light
model, near depth, frame alignment) and is what ``psrig normals`` and ``psrig run`` expose.
The measurements behind each default: docs/photometric-stereo.md.
"""

from dataclasses import dataclass

from ..core.errors import InputError
from ..core.options import Options, option

__all__ = ["SelectionOptions", "EstimateOptions", "BiquadraticOptions", "AlternationOptions", "NormalsOptions",
           "T_SHADOW", "WIDE_T_SHADOW", "WIDE_T_LOW", "WIDE_SPREAD_DEG", "REJECT_K", "SHAPE_PRIOR", "MAX_ITER", "TOL_DEG", "CONSENSUS", "UNCERTAIN_DEG", "FOLDS",
           "SCALE_FLOOR", "CONSENSUS_RADIUS", "CONSENSUS_SHARE", "CONSENSUS_MIN_NEIGHBOURS", "CONSENSUS_ROUNDS",
           "MEMORY_SHARE",
           "parse_fraction"]

#: observations below this fraction of the pixel's 90th-percentile intensity are shadows
#: (narrow light cones; wide sets use :data:`WIDE_T_SHADOW`)
T_SHADOW = 0.05
#: the shadow threshold over a wide light set (lights that reach grazing angles make dim
#: observations informative)
WIDE_T_SHADOW = 0.02
#: a light set wider than this (90th percentile of the angles from the mean light, degrees) is
#: solved with the paper's darkest-fraction rule
WIDE_SPREAD_DEG = 45.0
#: the darkest fraction kept over a wide light set (inside the paper's 20-40 %)
WIDE_T_LOW = 0.35
#: robust rejection threshold, in robust standard deviations of the pixel's residuals
REJECT_K = 2.5
#: the robust scale's floor, a fraction of the pixel's albedo (:func:`pipeline.photometric.selection.select_robust`)
SCALE_FLOOR = 0.01
#: triplets of lights the high-breakdown start of :func:`pipeline.photometric.selection.select_robust` tries per pixel
CONSENSUS = 48
#: the neighbour consensus (:mod:`pipeline.photometric.consensus`): an observation a pixel kept is
#: vetoed when more than CONSENSUS_SHARE of its object neighbours in the (2 r + 1)-pixel square
#: window (r = CONSENSUS_RADIUS) rejected it, and the pixel has at least CONSENSUS_MIN_NEIGHBOURS
#: of them (a strict majority of 5 x 5: docs/photometric-stereo.md, "Neighbour consensus"); the
#: vote is taken CONSENSUS_ROUNDS times, each on the decisions the last one left
CONSENSUS_RADIUS = 2
CONSENSUS_ROUNDS = 3
CONSENSUS_SHARE = 0.5
CONSENSUS_MIN_NEIGHBOURS = 3
#: folds over the lights of the held-out-light check (each light is held back once;
#: :mod:`pipeline.photometric.prediction`)
FOLDS = 5
#: the normals stage's default memory budget, a share of the available memory: a stack over it
#: is solved in tiles, which cost about what the whole-image solve costs (docs/big-captures.md),
#: so the stage does not take most of a workstation's memory because it could
MEMORY_SHARE = 0.5
#: a pixel whose expected angular error (degrees) is over this is 'uncertain', not 'ok'
#: (:mod:`pipeline.photometric.uncertainty`; docs/photometric-stereo.md, "Uncertainty")
UNCERTAIN_DEG = 20.0
#: weight of the pull toward the object's shared reflectance shape
SHAPE_PRIOR = 0.01
#: a pixel's fit stops when its Gauss-Newton step would turn the normal by less than this (degrees)
TOL_DEG = 0.1
#: Levenberg-Marquardt steps per pixel at most (accepted or not; pixels of the DiLiGenT objects
#: stop after 3-6)
MAX_ITER = 50

#: how an auto/on/off switch of the solver reads in the API ('auto' is the solver's own rule)
SOLVER_SWITCH = {"auto": "auto", "on": True, "off": False}
#: how an on/off flag reads in the API
ON_OFF = {"on": True, "off": False}


def parse_fraction(text):
    """A fraction in (0, 1] from '0.3' or a percentage ('30')."""
    value = float(text)
    value = value / 100.0 if value > 1 else value
    if not 0 < value <= 1:
        raise InputError(f"must be a fraction in (0, 1] or a percentage, got {text}")
    return value


@dataclass(frozen=True)
class SelectionOptions(Options):
    """Which observations each pixel's fit uses (:mod:`pipeline.photometric.selection`)."""

    kind = "photometric-stereo option"
    selection: str = option("auto", "observation selection: auto (from the light layout), robust or darkest",
                            choices=("auto", "robust", "darkest"), flag="")
    t_low: float = option(None, "use the paper's rule: keep the darkest fraction (0-1, or percent) of each "
                                "pixel's non-shadowed observations", kind=float, above=0.0, high=1.0,
                          parse=parse_fraction, metavar="F",
                          default_text=f"robust selection; {WIDE_T_LOW} over a light set wider than "
                                       f"{WIDE_SPREAD_DEG:g} degrees")
    t_shadow: float = option(None, "shadow threshold, a fraction of the pixel's 90th-percentile intensity",
                             kind=float, low=0.0, high=1.0, metavar="F",
                             default_text=f"{T_SHADOW} under a narrow light cone, {WIDE_T_SHADOW} over a wide set")
    reject_k: float = option(None, "robust rejection threshold in robust standard deviations", kind=float,
                             above=0.0, metavar="F", default_text=str(REJECT_K))
    consensus: int = option(CONSENSUS, "light triplets the robust start tries per pixel (0: no robust start)",
                            kind=int, low=0, flag="")
    scale_floor: float = option(SCALE_FLOOR, "the robust scale's floor, a fraction of the albedo", kind=float,
                                low=0.0, flag="")


@dataclass(frozen=True)
class EstimateOptions(Options):
    """What :func:`pipeline.photometric.estimate_normals` does around every method's fit."""

    kind = "photometric-stereo option"
    specular_anchor: object = option(
        "auto", "correct the lights' polar angles where sharp specular peaks show the normals' slant to be off "
                "(auto: the biquadratic under a narrow light cone)", cli=SOLVER_SWITCH)
    uncertain_deg: float = option(UNCERTAIN_DEG, "expected angular error (degrees) above which a pixel's status is "
                                                 "'uncertain' instead of 'ok' (its normal is kept)", kind=float,
                                  above=0.0, metavar="DEG")
    frame_gains: object = option(
        "auto", "check each frame's brightness against its light's intensity, from the images: auto rescales "
                "the frames more than 16 % off the others, on rescales every frame by its measured gain, off "
                "trusts the intensities", cli=SOLVER_SWITCH)


@dataclass(frozen=True)
class BiquadraticOptions(SelectionOptions):
    """The biquadratic method's options (:mod:`pipeline.photometric.biquadratic`)."""

    shape_prior: float = option(SHAPE_PRIOR, "pull toward the object's shared reflectance shape "
                                             "(0 = independent pixels as in the paper)", kind=float, low=0.0,
                                metavar="F")
    shared_shape: bool = option(None, "False: the Lambertian prior instead of the shared shape", kind=bool, flag="",
                                default_text="the shared shape, but over a wide light set")
    shape_check: bool = option(None, "False: keep the shared shape even when the object fails the "
                                     "single-material check", kind=bool, flag="", default_text="checked")
    max_iter: int = option(MAX_ITER, "Levenberg-Marquardt steps per pixel at most", kind=int, low=1, flag="")
    neighbour_consensus: bool = option(True, "after the selection, veto each observation a pixel kept that most of "
                                             "its object neighbours rejected, and select and fit those pixels again "
                                             "(robust selection only)", cli=ON_OFF)
    tol_deg: float = option(TOL_DEG, "a pixel stops when its step turns the normal by less than this (degrees)",
                            kind=float, above=0.0, flag="")


@dataclass(frozen=True)
class AlternationOptions(SelectionOptions):
    """The paper's alternation with a reflectance model (:class:`pipeline.photometric.methods.ModelAlternation`)."""

    max_iter: int = option(20, "alternation rounds at most", kind=int, low=1, flag="")
    tol: float = option(1e-7, "stop when every residual changes by at most this fraction", kind=float, low=0.0,
                        flag="")


@dataclass(frozen=True)
class NormalsOptions(BiquadraticOptions, EstimateOptions):
    """The ``normals`` stage's options: the method's (whichever it is) and the stage's own."""

    kind = "normals option"
    method: str = option("biquadratic", "photometric-stereo method: biquadratic, lambert, lambert-low, bicubic, "
                                        "bilinear or any registered model (psrig normals --list-methods)",
                         metavar="NAME")
    lights_model: str = option("auto", "near: per-pixel directions and falloff from calibrated light positions; "
                                       "auto: near when lights.yaml has positions the calibration kept",
                               choices=("auto", "directional", "near"))
    near_depth: bool = option(True, "near lights: solve again at the depth the first solve's normals integrate to "
                                    "(on) or keep the object on the plane of the calibration spheres (off)",
                              cli=ON_OFF)
    holdout_folds: int = option(FOLDS, "held-out-light check: refit the biquadratic and Lambertian models with "
                                       "each of this many folds of the lights held back and score their prediction "
                                       "of the held-back frames (0 = off; needs at least 6 lights)", kind=int,
                                low=0, metavar="N")
    align: str = option("auto", "frames that see the object shifted against the others: auto aligns them and "
                                "solves again where the object's shading pins position, off only says",
                        choices=("auto", "off"), flag="--align-frames")

    memory: str = option(None, "memory budget: bytes, 8G, 1500M or a share of the available memory such as 60%; a "
                               "stack over it is solved in tiles from a memory-mapped file, a run that cannot fit "
                               "is refused before it starts", kind=str, metavar="SIZE", recorded=False,
                         default_text=f"{MEMORY_SHARE:.0%} of the available memory")

    STAGE_FIELDS = ("method", "lights_model", "near_depth", "holdout_folds", "align", "memory")

    def record(self):
        """The stage record's parameters: the method always, the rest when not at their default."""
        return {"method": self.method, **{k: v for k, v in sorted(super().record().items()) if k != "method"}}

    def solver_options(self):
        """The options given to the method (not the stage's own), those not at their default."""
        return {k: v for k, v in self.given().items() if k not in self.STAGE_FIELDS}
