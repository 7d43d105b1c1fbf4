"""``psrig experiments {cook-torrance,merl,models,ps}``: the paper's tables and figures.

Each writes table.csv, table.md and figure.png into --out (default ./experiments-out/<name>/),
prints the Markdown table, and is deterministic (fixed seeds).
"""

import time
from pathlib import Path

from ..core.errors import InputError

__all__ = ["register", "parse_floats"]


def parse_floats(text, what="list"):
    """'0.1,0.2' -> (0.1, 0.2); InputError naming the option on a bad number."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise InputError(f"{what}: {text!r} is not a comma-separated list of numbers") from None
    if not values:
        raise InputError(f"{what}: empty list")
    return values


def _t_lows(text):
    values = parse_floats(text, "--t-low")
    if any(not 0 < t <= 1 for t in values):
        raise InputError(f"--t-low: every value must be in (0, 1], got {text!r}")
    return values


def _protocol_args(parser):
    parser.add_argument("--longitudes", type=int, default=36, help="normal longitudes (36)")
    parser.add_argument("--altitudes", type=int, default=45, help="normal altitudes (45)")
    parser.add_argument("--lights", type=int, default=100, help="random lights (100)")
    parser.add_argument("--seed", type=int, default=2012, help="light sampling seed (2012)")


def _protocol(args):
    if min(args.longitudes, args.altitudes, args.lights) < 1:
        raise InputError("--longitudes, --altitudes and --lights must be positive")
    return dict(n_longitudes=args.longitudes, n_altitudes=args.altitudes,
                n_lights=args.lights, seed=args.seed)


def register(subparsers):
    parser = subparsers.add_parser(
        "experiments", help="reproduce the paper's experiments (tables + figures)",
        description="The experiments of Shi et al. (CVPR 2012): Fig. 2 (cook-torrance), Fig. 3 "
                    "(merl), Fig. 4 (models), Fig. 5 (reflectometry), Fig. 6 (ps). Each writes table.csv, table.md and "
                    "figure.png into --out.")
    sub = parser.add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)

    ct = sub.add_parser("cook-torrance", help="Fig. 2: biquadratic fits to Cook-Torrance, m x T_low")
    ct.add_argument("--roughness", default="0.05,0.1,0.15,0.2,0.3,0.4,0.5,0.6,0.8,1.0")
    ct.add_argument("--t-low", default="0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0")
    _protocol_args(ct)
    ct.set_defaults(func=_run_cook_torrance)

    merl = sub.add_parser("merl", help="Fig. 3: the same on MERL .binary files in DIR")
    merl.add_argument("folder", metavar="DIR", help="folder of MERL *.binary files")
    merl.add_argument("--t-low", default="0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0")
    _protocol_args(merl)
    merl.set_defaults(func=_run_merl)

    models = sub.add_parser("models", help="Fig. 4: every model at T_low = 25 %%")
    models.add_argument("folder", metavar="DIR", nargs="?", help="optional folder of MERL files")
    models.add_argument("--t-low", type=float, default=0.25)
    models.add_argument("--roughness", default="0.1,0.2,0.3,0.5,0.7",
                        help="roughness of the generated Cook-Torrance and Ward materials")
    _protocol_args(models)
    models.set_defaults(func=_run_models)

    ps = sub.add_parser("ps", help="Fig. 6: photometric stereo with every model")
    ps.add_argument("--t-low", type=float, default=0.25)
    ps.add_argument("--size", type=int, default=96, help="rendered image size (pixels)")
    ps.add_argument("--lights", type=int, default=100)
    ps.add_argument("--seed", type=int, default=2012)
    ps.add_argument("--diligent", metavar="DIR", help="DiLiGenT folder with ballPNG, catPNG "
                    "(default ../shared/data/diligent if present)")
    ps.add_argument("--objects", default="ball,cat", help="DiLiGenT objects (default ball,cat)")
    ps.add_argument("--no-diligent", action="store_true", help="only the rendered object")
    ps.add_argument("--shadow", type=float, default=None,
                    help="shadow threshold, fraction of each pixel's 90th percentile (default: "
                         "0.01 on the noise-free rendering, 0.1 on DiLiGenT)")
    ps.add_argument("--no-psrig-default", action="store_true",
                    help="leave out the row of psrig's default estimator")
    ps.set_defaults(func=_run_ps)

    refl = sub.add_parser("reflectometry", help="Fig. 5 over the analytic materials: biquadratic vs the "
                          "bivariate table vs Lafortune and Lambert, from one image of a sphere")
    refl.add_argument("folder", metavar="DIR", nargs="?", help="optional folder of MERL files to add")
    refl.add_argument("--roughness", default="0.1,0.2,0.3,0.5,0.7",
                      help="roughness of the generated Cook-Torrance and Ward materials")
    refl.add_argument("--light", metavar="X,Y,Z", help="direction toward the light (default 0.4,0.3,0.866)")
    refl.add_argument("--size", type=int, default=128, help="simulated sphere image size (128)")
    refl.set_defaults(func=_run_reflectometry)

    for p in (ct, merl, models, ps, refl):
        p.add_argument("--out", metavar="DIR", help="output folder (default "
                       "./experiments-out/<experiment>)")


def _finish(args, name, table, figure, started):
    from ..experiments.tables import write_outputs

    out = Path(args.out or Path("experiments-out") / name)
    paths = write_outputs(out, table, figure)
    print(table.to_markdown())
    print(f"wrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - started:.1f} s")
    return 0


def _run_cook_torrance(args):
    from ..experiments import cook_torrance as exp

    started = time.perf_counter()
    roughness = parse_floats(args.roughness, "--roughness")
    if any(not 0 < m <= 1 for m in roughness):
        raise InputError(f"--roughness: every m must be in (0, 1], got {args.roughness!r}")
    t_lows = _t_lows(args.t_low)
    models = ("biquadratic", "biquadratic-factorised")
    mae = exp.cook_torrance_grid(roughness, t_lows, models, **_protocol(args))
    figure = exp.heatmap_figure(mae, [f"m={m:g}" for m in roughness], t_lows,
                                ["biquadratic (relaxed, Eq. 2)", "biquadratic (iterated, Eq. 1)"],
                                "Cook-Torrance roughness")
    return _finish(args, "cook-torrance", exp.cook_torrance_table(mae, roughness, t_lows, models,
                                                          **_protocol(args)),
                   figure, started)


def _run_merl(args):
    from ..experiments import merl as exp
    from ..experiments.cook_torrance import heatmap_figure

    started = time.perf_counter()
    files = exp.find_merl_files(args.folder)
    t_lows = _t_lows(args.t_low)
    models = ("biquadratic", "biquadratic-factorised")
    mae = exp.merl_grid(files, t_lows, models, **_protocol(args))
    table, order = exp.merl_table(mae, files, t_lows, models, **_protocol(args))
    figure = heatmap_figure(mae[:, order], [Path(files[i]).stem for i in order], t_lows,
                            ["biquadratic (relaxed)", "biquadratic (iterated)"], "material")
    return _finish(args, "merl", table, figure, started)


def _run_models(args):
    from ..experiments import models as exp
    from ..experiments.merl import find_merl_files

    started = time.perf_counter()
    if not 0 < args.t_low <= 1:
        raise InputError(f"--t-low must be in (0, 1], got {args.t_low}")
    files = find_merl_files(args.folder) if args.folder else ()
    roughness = parse_floats(args.roughness, "--roughness")
    mae, labels = exp.models_comparison(files, args.t_low, roughness, **_protocol(args))
    return _finish(args, "models", exp.models_table(mae, labels, args.t_low, **_protocol(args)),
                   exp.models_figure(mae, labels), started)


def _run_reflectometry(args):
    from ..experiments import reflectometry as exp
    from ..experiments.merl import find_merl_files

    started = time.perf_counter()
    roughness = parse_floats(args.roughness, "--roughness")
    if any(not 0 < m <= 1 for m in roughness):
        raise InputError(f"--roughness: every m must be in (0, 1], got {args.roughness!r}")
    if args.size < 16:
        raise InputError(f"--size must be at least 16, got {args.size}")
    light = parse_floats(args.light, "--light") if args.light else exp.DEFAULT_LIGHT
    if len(light) != 3:
        raise InputError(f"--light: expected 3 comma-separated numbers, got {args.light!r}")
    specs = [f"{name}:{m:g}" for name in ("cook-torrance", "ward") for m in roughness]
    specs += [str(f) for f in (find_merl_files(args.folder) if args.folder else ())]
    materials = [exp.parse_material(spec)[::-1] for spec in specs]
    mae, relative, counts, labels = exp.materials_comparison(materials, light, args.size)
    return _finish(args, "reflectometry", exp.materials_table(mae, relative, counts, labels, light, args.size),
                   exp.materials_figure(relative, counts, labels), started)


def _run_ps(args):
    from ..experiments import ps as exp

    started = time.perf_counter()
    if not 0 < args.t_low <= 1:
        raise InputError(f"--t-low must be in (0, 1], got {args.t_low}")
    images, lights, truth, mask, _ = exp.render_two_materials(args.size, args.lights, args.seed)
    shadows = (0.01, 0.1) if args.shadow is None else (args.shadow, args.shadow)
    extra = not args.no_psrig_default
    rendered = exp.run_methods(images, lights, mask, truth, args.t_low, shadow=shadows[0],
                               psrig_default=extra)
    columns = {"rendered (two materials)": rendered}
    folder = None if args.no_diligent else (Path(args.diligent) if args.diligent
                                             else exp.DEFAULT_DILIGENT)
    if args.diligent and not folder.is_dir():
        raise InputError(f"--diligent {folder}: no such folder")
    if folder is not None and folder.is_dir():
        for name in filter(None, args.objects.split(",")):
            columns[f"DiLiGenT {name}"] = exp.run_diligent(folder / f"{name}PNG", args.t_low,
                                                           shadow=shadows[1], psrig_default=extra)
    figure = exp.ps_figure(rendered, truth, mask, images[0])
    note = (f"Shadow threshold: {shadows[0]:g} (rendered), {shadows[1]:g} (DiLiGenT) x each "
            f"pixel's 90th percentile.")
    return _finish(args, "ps", exp.ps_table(columns, args.t_low, note), figure, started)
