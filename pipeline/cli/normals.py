"""``psrig normals SESSION [--method NAME] [--t-low F] ...``"""

from ..errors import InputError
from .writing import open_session


def register(sub):
    parser = sub.add_parser("normals", help="photometric stereo: linear frames + lights -> normals/")
    parser.add_argument("session", help="session folder")
    parser.add_argument("--method", default="biquadratic",
                        help="biquadratic (default), lambert, lambert-low, bicubic, or any registered model")
    parser.add_argument("--t-low", type=float, default=None,
                        help="use the paper's rule: keep the darkest fraction (0-1, or percent) of each "
                             "pixel's non-shadowed observations (default: robust selection)")
    parser.add_argument("--t-shadow", type=float, default=None, help="shadow threshold, fraction of the "
                        "pixel's 90th-percentile intensity (default 0.1)")
    parser.add_argument("--reject-k", type=float, default=None, help="robust rejection threshold in "
                        "robust standard deviations (default 2.5)")
    parser.add_argument("--shape-prior", type=float, default=None, help="pull toward the object's shared "
                        "reflectance shape (default 0.01; 0 = independent pixels as in the paper)")
    parser.add_argument("--lights-model", choices=("auto", "directional", "near"), default="auto",
                        help="near: per-pixel directions and falloff from calibrated light positions; "
                             "auto (default): near when lights.yaml has positions the calibration kept")
    parser.add_argument("--near-depth", choices=("on", "off"), default="on",
                        help="near lights: solve again with the per-pixel directions at the depth the "
                             "first solve's normals integrate to (on, the default) or keep the object "
                             "on the plane of the calibration spheres (off)")
    parser.add_argument("--specular-anchor", choices=("auto", "on", "off"), default="auto",
                        help="correct the lights' polar angles where sharp specular peaks show the "
                             "normals' slant to be off (auto, the default: biquadratic under a narrow "
                             "light cone)")
    parser.add_argument("--frame-gains", choices=("auto", "on", "off"), default="auto",
                        help="check each frame's brightness against its light's intensity, from the "
                             "images: auto (the default) rescales the frames that are more than 16 %% "
                             "off the others, on rescales every frame by its measured gain, off trusts "
                             "the intensities")
    parser.add_argument("--align-frames", choices=("auto", "off"), default="auto",
                        help="frames that see the object shifted against the others (it or the camera "
                             "moved): auto (the default) aligns them by their measured shift and solves "
                             "again where the object's shading pins position, off only says")
    parser.add_argument("--memory", default=None, metavar="SIZE",
                        help="memory budget: bytes, 8G, 1500M or a share of the available memory such as 60%%"
                             " (default 80%% of the available memory); a stack over it is solved in tiles "
                             "from a memory-mapped file, a run that cannot fit is refused before it starts")
    parser.add_argument("--force", action="store_true", help="run even when the stage is up to date")
    parser.set_defaults(func=run)


def _switch(value):
    """auto / on / off as the stage's option: None (its default), True, False."""
    return {"auto": None, "on": True, "off": False}[value]


def run(args):
    from ..photometric import normals_session, normals_summary

    t_low = args.t_low
    if t_low is not None:
        t_low = t_low / 100.0 if t_low > 1 else t_low
        if not 0 < t_low <= 1:
            raise InputError(f"--t-low must be a fraction in (0, 1] or a percentage, got {args.t_low}")
    session = open_session(args.session, args)
    record = normals_session(session, method=args.method, force=args.force, t_low=t_low,
                             lights_model=args.lights_model, near_depth=args.near_depth == "on",
                             specular_anchor=_switch(args.specular_anchor), frame_gains=_switch(args.frame_gains),
                             t_shadow=args.t_shadow, reject_k=args.reject_k, shape_prior=args.shape_prior,
                             align=args.align_frames, memory=args.memory)
    if record is None:
        print(f"{session.root}: normals up to date (use --force to rerun)")
        return 0
    print(f"{session.root}: normals ({args.method}) in {record['seconds']:.2f} s; {normals_summary(record)}")
    budget = record.get("memory")
    if budget:
        print(f"{session.root}: normals: {budget['execution']}, estimated peak {budget['estimate_gb']:.2f} GB "
              f"within a budget of {budget['budget_gb']:.2f} GB (--memory)")
    for warning in record.get("warnings", []):
        print(f"{session.root}: normals: warning: {warning}")
    return 0
