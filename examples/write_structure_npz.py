"""Write a modal model of the telescope structure for the `structure` FMU (`modal_file`).

Usage (numpy only):

    python examples/write_structure_npz.py --layout keck --output keck_structure.npz
    # then, e.g. with fmpy:
    # simulate_fmu("target/fmu/keck/structure.fmu",
    #              start_values={"modal_file": "/abs/path/keck_structure.npz"}, ...)

The file is a NumPy .npz archive of little-endian float64 arrays (n modes, na = 3 x segments
actuators; actuator k of segment i has index 3 i + k):

    frequencies     (n,)      Hz          natural frequencies, all > 0
    phi_cell        (na, n)   1/sqrt(kg)  mass-normalised mode shapes (Phi^T M Phi = I), vertical
                                          displacement at the actuator attachment nodes
    phi_pier        (n,)      1/sqrt(kg)  mode shapes at the node where the pier spring attaches
    k_pier          ()        N/m         the pier spring, grounded in the FE model
    damping_ratios  (n,)      1           optional (else the FMU's damping_ratio parameter)
    flexibility     (na, na)  m/N         optional: static compliance K^-1 at the attachment
                                          nodes (enables the static correction of f_cell)
    static_pier     (na,)     m/m         optional: static z_cell per metre of pier_z (all ones
                                          when the pier spring is the structure's only ground)

How to export from your own FE model: ground the structure through one vertical spring k_pier
at the pier node (a stiff spring approximates an enforced pier displacement), compute the modes
normalised to unit modal mass, and take the rows of the vertical DOFs at the actuator attachment
nodes (phi_cell) and at the pier node (phi_pier). The FMU drives the modes with
u = phi_cell^T f_cell + k_pier phi_pier pier_z.

The demonstration model written here (when run as a script) is a small lumped FE model: each
attachment node (mass m) hangs on the mount node (mass M) through a spring k_a, neighbouring
attachment nodes are coupled by springs k_c, and the mount rests on the pier spring k_pier.
`write_modal_npz` is the part to reuse with your own FE results.
"""
import argparse

import numpy as np

N_SEGMENTS = {"keck": 36, "tmt": 492, "elt": 798}


def write_modal_npz(path, frequencies, phi_cell, phi_pier, k_pier, damping_ratios=None,
                    flexibility=None, static_pier=None, compressed=True):
    """Checks shapes and writes the arrays with the names and dtypes the FMU expects."""
    f8 = np.dtype("<f8")
    frequencies = np.asarray(frequencies, dtype=f8)
    n = frequencies.shape[0]
    phi_cell = np.asarray(phi_cell, dtype=f8)
    na = phi_cell.shape[0]
    if frequencies.ndim != 1 or np.any(frequencies <= 0):
        raise ValueError("frequencies must be a 1-d array of positive values (Hz)")
    if phi_cell.shape != (na, n):
        raise ValueError(f"phi_cell must be (na, {n}), got {phi_cell.shape}")
    arrays = {
        "frequencies": frequencies,
        "phi_cell": phi_cell,
        "phi_pier": np.asarray(phi_pier, dtype=f8).reshape(n),
        "k_pier": np.asarray(k_pier, dtype=f8).reshape(()),
    }
    if damping_ratios is not None:
        arrays["damping_ratios"] = np.asarray(damping_ratios, dtype=f8).reshape(n)
    if flexibility is not None:
        g = np.asarray(flexibility, dtype=f8)
        if g.shape != (na, na):
            raise ValueError(f"flexibility must be ({na}, {na}), got {g.shape}")
        arrays["flexibility"] = 0.5 * (g + g.T)
    if static_pier is not None:
        arrays["static_pier"] = np.asarray(static_pier, dtype=f8).reshape(na)
    (np.savez_compressed if compressed else np.savez)(path, **arrays)


def demo_model(na, m=100.0, mount_mass=None, k_a=2e8, k_c=5e7, k_pier=None):
    """Stiffness and mass of the lumped demonstration model (mount DOF last)."""
    mount_mass = mount_mass if mount_mass is not None else 2.0 * m * na
    n = na + 1
    k = np.zeros((n, n))
    for i in range(na):
        k[i, i] += k_a
        k[na, na] += k_a
        k[i, na] -= k_a
        k[na, i] -= k_a
        j = (i + 1) % na
        k[i, i] += k_c
        k[j, j] += k_c
        k[i, j] -= k_c
        k[j, i] -= k_c
    if k_pier is None:
        # Rigid structure bouncing on the pier at 8 Hz.
        k_pier = (2 * np.pi * 8.0) ** 2 * (m * na + mount_mass)
    k[na, na] += k_pier
    mass = np.full(n, m)
    mass[na] = mount_mass
    return k, mass, k_pier


def modes(k, mass):
    """Mass-normalised modes of K x = w^2 M x (M diagonal), frequencies in Hz."""
    d = 1.0 / np.sqrt(mass)
    lam, v = np.linalg.eigh(d[:, None] * k * d[None, :])
    return np.sqrt(lam) / (2 * np.pi), d[:, None] * v


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--layout", choices=sorted(N_SEGMENTS), default="keck")
    ap.add_argument("--modes", type=int, default=0, help="modes to export (0: all)")
    ap.add_argument("--damping", type=float, default=None, help="damping ratio of every mode")
    ap.add_argument("--output", default="structure_modes.npz")
    args = ap.parse_args()
    na = 3 * N_SEGMENTS[args.layout]
    k, mass, k_pier = demo_model(na)
    freq, phi = modes(k, mass)
    keep = slice(None) if args.modes <= 0 else slice(0, args.modes)
    flex = np.linalg.inv(k)[:na, :na]
    write_modal_npz(
        args.output,
        frequencies=freq[keep],
        phi_cell=phi[:na, keep],
        phi_pier=phi[na, keep],
        k_pier=k_pier,
        damping_ratios=None if args.damping is None else np.full(freq[keep].size, args.damping),
        flexibility=flex,
        static_pier=np.ones(na),
    )
    print(f"{args.output}: {freq[keep].size} modes, {freq[0]:.2f}..{freq[keep][-1]:.1f} Hz, "
          f"na = {na}")


if __name__ == "__main__":
    main()
