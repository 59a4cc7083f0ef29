"""A co-adaptation config with some keys changed: prints BASE with each KEY.PATH=VALUE applied.

usage: python3 scripts/config_with.py BASE.toml learner.population-only=true optimizer.q='"pessimistic"' ...

VALUE is TOML (strings need their quotes). Tables that the override path names are created.
Used by scripts/campaign.sh for experiment variants (`CONFIG+key=value+key=value`).
"""
import json
import sys
import tomllib


def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r}")


def write(table, prefix, out):
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if prefix and scalars:
        out.append(f"\n[{prefix}]")
    for k, v in scalars.items():
        out.append(f"{k} = {toml_value(v)}")
    for k, v in tables.items():
        write(v, f"{prefix}.{k}" if prefix else k, out)


def main():
    base, overrides = sys.argv[1], sys.argv[2:]
    with open(base, "rb") as f:
        cfg = tomllib.load(f)
    for o in overrides:
        path, _, value = o.partition("=")
        if not value:
            sys.exit(f"config_with: override {o!r} is not KEY.PATH=VALUE")
        keys = path.split(".")
        t = cfg
        for k in keys[:-1]:
            t = t.setdefault(k, {})
        t[keys[-1]] = tomllib.loads(f"v = {value}")["v"]
    out = [f"# {base} with {' '.join(overrides)} (scripts/config_with.py)"]
    write(cfg, "", out)
    print("\n".join(out))


if __name__ == "__main__":
    main()
