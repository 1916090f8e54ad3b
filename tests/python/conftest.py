"""Shared fixtures: where the packaged FMUs are, and helpers to read their parameters."""
import os
import pathlib

import pytest
from fmpy import read_model_description

ROOT = pathlib.Path(__file__).resolve().parents[2]
FMU_DIR = pathlib.Path(os.environ.get("M1CS_FMU_DIR", ROOT / "target" / "fmu"))


def all_fmus():
    """Every packaged archive, as (layout, path)."""
    return sorted((p.parent.name, p) for p in FMU_DIR.glob("*/*.fmu"))


def fmu_path(layout, name):
    p = FMU_DIR / layout / f"{name}.fmu"
    if not p.exists():
        pytest.fail(f"{p} is missing: run `cargo xtask package` first")
    return p


def start_values(path):
    """Start values of every scalar variable, by name (floats, ints, bools, strings)."""
    md = read_model_description(str(path))
    out = {}
    for v in md.modelVariables:
        if v.start is None:
            continue
        if v.type == "Real":
            out[v.name] = float(v.start)
        elif v.type == "Integer":
            out[v.name] = int(v.start)
        elif v.type == "Boolean":
            out[v.name] = v.start in ("true", "1", True)
        else:
            out[v.name] = v.start
    return out


def pytest_collection_modifyitems(config, items):
    if not all_fmus():
        raise pytest.UsageError(f"no FMUs under {FMU_DIR}: run `cargo xtask package` first")
