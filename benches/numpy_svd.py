#!/usr/bin/env python3
"""Wall time of NumPy's SVD of the dense TMT A-matrix, for comparison with faer.

Loads the A-matrix (2772 x 1476 for TMT) that the criterion benchmark
crates/m1/benches/quasistatic.rs writes as an NPY file (target/m1-bench/a_tmt.npy) and times

  svd_uv    np.linalg.svd(A, full_matrices=False)   (thin U, S, V^T: LAPACK dgesdd)
  svd_s     np.linalg.svd(A, compute_uv=False)      (singular values only)

each --repeat times (after one untimed warm-up call), reporting the best and the median wall
time. It prints NumPy's BLAS/LAPACK configuration and the number of BLAS threads, and, if the
benchmark also wrote faer's singular values (target/m1-bench/sv_faer_tmt.npy), the largest
relative difference between the two sets of singular values.

The number of BLAS threads is set before NumPy is imported (--threads, default 2: one per core
of the benchmark machine) through OPENBLAS_NUM_THREADS / OMP_NUM_THREADS / MKL_NUM_THREADS,
unless already set in the environment.

Usage: .venv/bin/python benches/numpy_svd.py [--a PATH] [--faer-sv PATH] [--repeat 5]
       [--threads 2]
Write the inputs first: cargo bench -p m1 --bench quasistatic -- svd_tmt
"""

import argparse
import ctypes
import glob
import os
import pathlib
import platform
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
DEFAULT_DIR = ROOT / "target" / "m1-bench"


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--a", default=str(DEFAULT_DIR / "a_tmt.npy"), help="the dense A (.npy)")
    p.add_argument(
        "--faer-sv",
        default=str(DEFAULT_DIR / "sv_faer_tmt.npy"),
        help="faer's singular values (.npy), compared if present",
    )
    p.add_argument("--repeat", type=int, default=5, help="timed runs per case")
    p.add_argument("--threads", type=int, default=2, help="BLAS threads (default 2)")
    return p.parse_args()


ARGS = parse_args()
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, str(ARGS.threads))

import numpy as np  # noqa: E402


def openblas_info():
    """(config, core, threads) of the OpenBLAS bundled with NumPy, via ctypes; None if absent."""
    libs_dir = pathlib.Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for path in sorted(glob.glob(str(libs_dir / "*openblas*.so*"))):
        lib = ctypes.CDLL(path)
        # scipy-openblas wheels prefix and suffix their symbols; plain OpenBLAS does not.
        candidates = (("scipy_openblas_", "64_"), ("scipy_openblas_", ""), ("openblas_", ""))
        for prefix, suffix in candidates:
            try:
                get_config = getattr(lib, f"{prefix}get_config{suffix}")
                get_core = getattr(lib, f"{prefix}get_corename{suffix}")
                get_threads = getattr(lib, f"{prefix}get_num_threads{suffix}")
            except AttributeError:
                continue
            get_config.restype = ctypes.c_char_p
            get_core.restype = ctypes.c_char_p
            get_threads.restype = ctypes.c_int
            return get_config().decode(), get_core().decode(), get_threads()
    return None


def print_config():
    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.platform()}")
    print(f"os.cpu_count() = {os.cpu_count()}, sched_getaffinity = {len(os.sched_getaffinity(0))}")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        print(f"{var}={os.environ.get(var)}")
    try:
        import threadpoolctl  # noqa: PLC0415

        for pool in threadpoolctl.threadpool_info():
            print(f"threadpoolctl: {pool}")
    except ImportError:
        print("threadpoolctl: not installed")
    info = openblas_info()
    if info is not None:
        config, core, threads = info
        print(f"OpenBLAS config: {config}")
        print(f"OpenBLAS core: {core}; BLAS threads: {threads}")
    deps = np.show_config(mode="dicts").get("Build Dependencies", {})
    for name in ("blas", "lapack"):
        d = deps.get(name, {})
        config = d.get("openblas configuration", "")
        print(f"numpy {name}: {d.get('name')} {d.get('version')} ({config})")


def timed(fn, repeat):
    fn()  # warm-up
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times), out


def main():
    print_config()
    a = np.load(ARGS.a)
    print(f"A: {ARGS.a}, shape {a.shape}, dtype {a.dtype}, fortran order {a.flags.f_contiguous}, "
          f"{np.count_nonzero(a)} non-zeros")
    cases = {
        "svd_uv": lambda: np.linalg.svd(a, full_matrices=False),
        "svd_s": lambda: np.linalg.svd(a, compute_uv=False),
    }
    results = {}
    print(f"\n{'case':<8} {'best s':>8} {'median s':>9}   ({ARGS.repeat} runs)")
    for name, fn in cases.items():
        best, med, out = timed(fn, ARGS.repeat)
        results[name] = out
        print(f"{name:<8} {best:>8.3f} {med:>9.3f}")

    u, s, vt = results["svd_uv"]
    resid = np.linalg.norm(a - (u * s) @ vt) / np.linalg.norm(a)
    orth = np.abs(vt @ vt.T - np.eye(vt.shape[0])).max()
    print(f"\nnumpy: s_max = {s[0]:.6e}, s_min = {s[-1]:.6e}, ||A - U S V^T||_F / ||A||_F = "
          f"{resid:.2e}, max |V^T V - I| = {orth:.2e}")
    s_only = results["svd_s"]
    print(f"numpy svd_s vs svd_uv: max |ds| / s_max = {np.abs(s_only - s).max() / s[0]:.2e}")

    if os.path.exists(ARGS.faer_sv):
        f = np.load(ARGS.faer_sv)
        if f.shape != s.shape:
            print(f"faer singular values: shape {f.shape} differs from numpy's {s.shape}")
            return 1
        d = np.abs(f - s)
        rel = d / s
        print(f"faer vs numpy singular values ({ARGS.faer_sv}):")
        print(f"  max |ds| / s_max                      = {d.max() / s[0]:.2e}")
        print(f"  max |ds| / s (all {len(s)})               = {rel.max():.2e} "
              f"(at index {rel.argmax()}, s = {s[rel.argmax()]:.3e})")
        for tol in (1e-6, 1e-10):
            keep = s > tol * s[0]
            print(f"  max |ds| / s over s > {tol:g} s_max ({keep.sum()}) = {rel[keep].max():.2e}")
        print(f"  smallest 4 (numpy): {', '.join(f'{x:.6e}' for x in s[-4:])}")
        print(f"  smallest 4 (faer):  {', '.join(f'{x:.6e}' for x in f[-4:])}")
    else:
        print(f"(no faer singular values at {ARGS.faer_sv}; run the criterion benchmark first)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
