"""mkcfg.py OUT key.path=value ...: the default config with overrides, written as YAML."""
import os, sys, yaml
sys.path.insert(0, os.environ.get("WT", "/work/i43m"))
d = yaml.safe_load(open(os.environ.get("WT", "/work/i43m") + "/config/default.yaml"))
for kv in sys.argv[2:]:
    k, v = kv.split("=", 1)
    node = d
    parts = k.split(".")
    for p in parts[:-1]:
        node = node[p]
    if parts[-1] not in node: sys.exit(f"no key {k}")
    node[parts[-1]] = yaml.safe_load(v)
yaml.safe_dump(d, open(sys.argv[1], "w"), sort_keys=False)
from config.loader import load_config
load_config(sys.argv[1])
