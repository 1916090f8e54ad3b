"""Shared fixtures: where the packaged FMUs are, and helpers to read their parameters."""
import ctypes
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


# fmpy 0.3.32 formats the FMUs' variadic log messages in a native proxy (fmpy/logging) that keeps
# the Python logger of the *last* simulate_fmu(logger=...) call in a process-wide global. Once
# that call returns, its ctypes callback is freed, and the next FMU that logs anything through
# fmpy's default callbacks jumps into freed memory (a segfault in an unrelated later test).
# After every test, point the proxy back at a logger that lives as long as the process.
_KEPT_CALLBACKS = []


def _reinstall_fmpy_logger_proxy():
    try:
        from fmpy.fmi1 import printLogMessage
        from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
        from fmpy.logging import addLoggerProxy
    except Exception:  # an fmpy without the proxy has no such global
        return
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(printLogMessage)
    _KEPT_CALLBACKS.append(callbacks)
    addLoggerProxy(ctypes.byref(callbacks))


@pytest.fixture(autouse=True)
def _fmpy_logger_proxy_guard():
    yield
    _reinstall_fmpy_logger_proxy()
