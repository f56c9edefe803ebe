"""``aider-exo config``: check a configuration file before it reaches a bus; estimate a patient's
body model from mass and height."""

from __future__ import annotations

import argparse
from pathlib import Path

from tools.cli.common import positive_float, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="check a configuration file (every key, range and cross-check)")
    csub = p.add_subparsers(dest="config_command", metavar="CONFIG_COMMAND", required=True)
    c = csub.add_parser("check", help="load FILE as aider-exo would; one line naming the file and key if it is wrong",
                        description="Loads FILE with every check the commands apply (types, ranges, choices, unknown keys, "
                                    "cross-field checks) and says which sections it has; a bad file is one line naming "
                                    "the file, the key and the problem, and exit status 1.")
    c.add_argument("file", type=Path, metavar="FILE", help="YAML configuration (config/default.yaml is the packaged one)")
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.set_defaults(func=run_check)
    b = csub.add_parser("body", help="controller.legs and controller.body estimated for a patient's mass and height (YAML)",
                        description="Prints the controller's body model (controller.legs, controller.body) for a patient of "
                                    "--mass and --height with sticks of --stick-length, estimated the way the simulated "
                                    "patient is built (Winter's anthropometric tables, segment by segment), as YAML to put in "
                                    "the patient's configuration. Replace every value you have measured, above all the "
                                    "exoskeleton's thigh and shank as adjusted (docs/DEPLOY.md, section 5).")
    b.add_argument("--mass", type=positive_float, required=True, metavar="KG", help="the patient's body mass")
    b.add_argument("--height", type=positive_float, required=True, metavar="M", help="the patient's body height")
    b.add_argument("--stick-length", type=positive_float, metavar="M",
                   help="the sticks (crutches), grip to tip (default: the packaged model's, scaled with the height)")
    b.add_argument("--config", metavar="FILE", help="take the anthropometric model from FILE's sim section "
                                                    "(default: the packaged configuration)")
    b.add_argument("--json", action="store_true", help="print the values as JSON instead of YAML")
    b.set_defaults(func=run_body)


def run_check(args: argparse.Namespace) -> int:
    from config import SCHEMA_VERSION, ConfigError, config_hash, load_config

    try:
        cfg = load_config(args.file)
    except ConfigError as exc:
        if args.json:  # the answer on stdout as well: a JSON object saying what is wrong (the one line on stderr too)
            print_json({"file": str(args.file), "valid": False, "error": str(exc), "key": exc.key, "line": exc.line})
        raise
    sections = {name: getattr(cfg, name) is not None for name in ("protocol", "hardware", "controller", "sim", "nodes")}
    result = {"file": str(args.file), "valid": True, "schema_version": SCHEMA_VERSION, "hash": config_hash(cfg),
              "bus": f"{cfg.bus.interface}:{cfg.bus.channel}", "sections": sections}
    if cfg.controller is not None:
        result["step_m"], result["swing_s"] = _scaled(cfg.controller)
    if args.json:
        print_json(result)
    else:
        present = ", ".join(name for name, there in sections.items() if there) or "none"
        print(f"{args.file}: valid (schema {SCHEMA_VERSION}, bus {result['bus']}; sections: {present}; hash {result['hash'][:12]})")
        if "step_m" in result:
            print(_step_line(result["step_m"], result["swing_s"]))
    return 0


def _scaled(controller) -> tuple[dict[str, float], float]:
    """controller.step's fractions in metres and the swing's duration in seconds, for this
    configuration's leg length."""
    from controller.factory import step_bounds, swing_duration_s

    b = step_bounds(controller)
    return ({"leg_length": round(controller.legs.length_m, 4), "init": round(b.init_m, 4), "min": round(b.min_m, 4),
             "max": round(b.max_m, 4)}, swing_duration_s(controller))


def _step_line(m: dict[str, float], swing_s: float) -> str:
    return (f"controller.step for a leg of {m['leg_length']:.3f} m: g_init {m['init']:.3f} m, "
            f"steps {m['min']:.3f}-{m['max']:.3f} m; swings of {swing_s:.3f} s")


#: the patient's options, for errors in their terms (the keys as tools.population names them)
_BODY_OPTIONS = {"mass_kg": "--mass", "height_m": "--height", "stick_length_m": "--stick-length"}


def run_body(args: argparse.Namespace) -> int:
    import yaml

    from config import ConfigError, default_config_path, load_config, with_overrides
    from config.loader import config_to_dict
    from tools.population import estimated_body

    base = load_config(args.config or default_config_path())
    if base.sim is None:
        raise ConfigError("has no sim section: the body is estimated with the simulation's anthropometric model "
                          "(leave out --config to use the packaged one)", key="sim", source=args.config)
    stick_m = args.stick_length or base.hardware.sticks.length_m * args.height / base.sim.model.patient.height_m
    try:
        overrides = estimated_body(base, mass_kg=args.mass, height_m=args.height, stick_m=stick_m, source="aider-exo config body")
        patient = with_overrides(base, overrides, source="aider-exo config body")  # its checks too
        controller = config_to_dict(patient)["controller"]
    except ConfigError as exc:
        option = _BODY_OPTIONS.get(exc.key or "")
        if option is None:
            raise
        raise ConfigError(f"{option}: {exc.message}") from None
    nested: dict = {"controller": {"legs": {}, "body": {}}}
    for key in overrides:  # controller.SECTION.NAME, in fitted_body's order
        _, section, name = key.split(".")
        value = controller[section][name]
        nested["controller"][section][name] = [round(v, 4) for v in value] if isinstance(value, list) else round(value, 4)
    step, swing_s = _scaled(patient.controller)
    if args.json:
        print_json({"mass_kg": args.mass, "height_m": args.height, "stick_length_m": round(stick_m, 4), "step_m": step,
                    "swing_s": swing_s, **nested})
        return 0
    print(f"# controller.legs and controller.body for a patient of {args.mass:g} kg and {args.height:g} m with sticks of\n"
          f"# {stick_m:.3f} m, estimated by `aider-exo config body` (Winter's tables). Replace every value you have\n"
          "# measured, above all the exoskeleton's thigh and shank as adjusted; then `aider-exo config check FILE`.\n"
          f"# {_step_line(step, swing_s)} (scaled with the leg length).")
    class Dumper(yaml.SafeDumper):  # blocks for the sections, [x, y, z] for the vectors
        pass

    Dumper.add_representer(list, lambda dumper, v: dumper.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True))
    print(yaml.dump(nested, Dumper=Dumper, sort_keys=False, default_flow_style=False), end="")
    return 0
