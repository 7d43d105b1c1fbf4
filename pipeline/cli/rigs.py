"""``psrig rigs``: list and validate the rigs of rigs.yaml; optionally talk to a rig's lights."""

import yaml

__all__ = ["register", "run", "format_rig_table", "format_driver_table"]


def register(subparsers):
    parser = subparsers.add_parser(
        "rigs", help="list and validate the rigs in rigs.yaml",
        description="List the rigs of the rig file (validating every one of them). "
                    "The file is --config, else $PSRIG_RIGS, else ./rigs.yaml, else psrig's own.")
    parser.add_argument("--config", metavar="FILE", help="rig file to read instead of rigs.yaml")
    parser.add_argument("--show", metavar="NAME", help="print one rig's full resolved definition")
    parser.add_argument("--check-lights", metavar="NAME", dest="check_lights",
                        help="connect to the rig's light controller: ID?, STATE?, OFF")
    parser.set_defaults(func=run)


def _lights_text(lights):
    from rig.drivers import light_driver

    return f"{lights.driver} x{lights.count} {light_driver(lights.driver).describe(lights)}".rstrip()


def _camera_text(camera):
    from rig.drivers import camera_driver

    if camera.driver == "sim":
        return "sim"
    return f"{camera.driver} {camera_driver(camera.driver).describe(camera)}".rstrip()


def format_driver_table():
    """One line per driver found: kind, name, built in or plugin, what it is (or why not)."""
    from rig.drivers import driver_table

    rows = [("DRIVER", "NAME", "FROM", "")] + driver_table()
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    return "\n".join("  ".join(cell.ljust(width) for cell, width in zip(row, widths + [0])).rstrip()
                     for row in rows)


def format_rig_table(rigs):
    """One line per rig: name, lights (driver x count, port), camera (driver, path, USB ids)."""
    rows = [("NAME", "LIGHTS", "CAMERA", "DESCRIPTION")]
    rows += [(name, _lights_text(rig.lights), _camera_text(rig.camera), rig.description)
             for name, rig in rigs.items()]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    widths.append(0)
    return "\n".join("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip()
                     for row in rows)


def _check_lights(rig):
    from rig.drivers import make_light_controller

    with make_light_controller(rig.lights) as controller:
        version, count = controller.identify()
        lit = controller.state()
        print(f"{rig.name}: {controller.port}: psrig light protocol {version}, {count} lights, "
              f"{'none' if lit is None else f'light {lit}'} lit; switching off")


def run(args):
    from rig.config import ConfigError, find_rigs_file, load_rigs

    rigs = load_rigs(args.config)
    source = find_rigs_file(args.config) or "(built in: sim only)"
    for wanted in filter(None, (args.show, args.check_lights)):
        if wanted not in rigs:
            raise ConfigError(f"{source}: no rig named {wanted!r} (rigs: {', '.join(rigs)})")
    if args.show:
        print(yaml.safe_dump({args.show: rigs[args.show].to_dict()}, sort_keys=False,
                             default_flow_style=None, width=100), end="")
        return 0
    if args.check_lights:
        _check_lights(rigs[args.check_lights])
        return 0
    print(format_rig_table(rigs))
    print(f"{len(rigs)} rig{'s' * (len(rigs) != 1)}, all valid ({source})")
    print()
    print(format_driver_table())
    return 0
