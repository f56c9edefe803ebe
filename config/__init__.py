"""Typed configuration of aider-exo.

Typical use::

    from config import ConfigError, default_config_path, load_config

    try:
        cfg = load_config(path or default_config_path())
    except ConfigError as exc:
        sys.exit(f"error: {exc}")  # one line: file, dotted key, problem
    bus = make_bus(cfg.bus)        # each component gets only its section
"""

from .errors import AiderError
from .loader import (
    ConfigError,
    FieldError,
    FieldSpec,
    build,
    check_schema,
    config_hash,
    config_to_dict,
    default_config_path,
    fail,
    field_spec,
    load_as,
    load_config,
    load_yaml,
    parse_as,
    parse_config,
    parse_override,
    with_overrides,
)
from .schema import SCHEMA_VERSION, BusConfig, Config, ProtocolConfig

__all__ = [
    "SCHEMA_VERSION",
    "AiderError",
    "BusConfig",
    "Config",
    "ConfigError",
    "FieldError",
    "FieldSpec",
    "ProtocolConfig",
    "build",
    "check_schema",
    "config_hash",
    "config_to_dict",
    "default_config_path",
    "fail",
    "field_spec",
    "load_as",
    "load_config",
    "load_yaml",
    "parse_as",
    "parse_config",
    "parse_override",
    "with_overrides",
]
