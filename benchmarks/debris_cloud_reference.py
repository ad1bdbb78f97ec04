"""The debris cloud's hydrodynamics against an independent Eulerian code: the cloud's axis in jaxmpm
and in tests/axisymmetric_euler.py (a 2D axisymmetric finite-volume solver of the Euler equations
with the same Mie-Grueneisen EOS: Riemann fluxes, no artificial viscosity, no particles).

Both solve the impact of the built-in `debris_cloud` (al2024 sphere of 9.53 mm at 6.71 km/s on a
2.21 mm plate) in the hydrodynamic model: no strength, no closure, no tension (the reference floors
p at 0; jaxmpm runs `mie_gruneisen+spall` with sigma_spall = 1 Pa), float64, to 6 us. Rows:
'reference' at --reference-cells (mm), 'jaxmpm hydrodynamic' and, for comparison, 'jaxmpm scene'
(the scene's own `tensile` configuration with strength and the closure at C_h = --c-h) at
--resolutions (cells of 0.4 mm / resolution). Measures on the axis, the same on both codes: the
leading 0.3 mm (areal mass) of the plate's material within 1 mm of the axis and the projectile's
front and rear 0.3 mm there, their mass-weighted u_z averaged over 3-6 us after the contact (km/s,
points 1, 2 and 4 on the axis); 'front' the slope of the cloud's front over 3-6 us (reference: the z
below which 1e-4 of the mass lies; jaxmpm: point 1's soft minimum). The experiment's leading edge:
6.3 km/s; the planar release of the same plate: 6.895 km/s.

Output: a CSV (--out, default benchmarks/results/debris_cloud_reference.csv) and a PNG next to it
(the plate's leading axial velocity against time for each row; the reference's density at 6 us
beside jaxmpm's particles at the finest resolution).

Run:  python benchmarks/debris_cloud_reference.py                          # 0.2 and 0.1 mm, resolutions 1, 2, 3
      python benchmarks/debris_cloud_reference.py --reference-cells 0.2 --resolutions 2 --out X.csv   # 10 minutes
"""

from __future__ import annotations

import argparse
import os
import platform
import sys

import jax
import numpy as np
from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs, print_and_write_table  # benchmarks/outputs.py

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
EXPERIMENT, PLANAR = 6.3, 6.895  # km/s
WINDOW = (3e-6, 6e-6)


def window_mean(t, u):
    keep = (t >= WINDOW[0] - 1e-9) & (t <= WINDOW[1] + 1e-9)
    return -float(np.mean(u[keep])) / 1e3


def window_slope(t, z):
    keep = (t >= WINDOW[0] - 1e-9) & (t <= WINDOW[1] + 1e-9)
    return -float(np.polyfit(t[keep], z[keep], 1)[0]) / 1e3


def row(code, cells_mm, run):
    return dict(
        code=code,
        cells_mm=cells_mm,
        plate_front_km_s=window_mean(run["t"], run["plate"]),
        projectile_front_km_s=window_mean(run["t"], run["projectile_front"]),
        projectile_rear_km_s=window_mean(run["t"], run["projectile_rear"]),
        cloud_front_km_s=window_slope(run["t"], run["front"]),
        wall_s=run["wall"],
    )


def figure(path, runs, reference, particles):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5.5))
    for label, t, u in runs:
        a.plot(t * 1e6, -u / 1e3, label=label)
    a.axhline(EXPERIMENT, color="k", ls="--", lw=1, label="experiment's leading edge (6.3 km/s)")
    a.axhline(PLANAR, color="0.5", ls=":", lw=1, label="planar release of the plate (6.895 km/s)")
    a.set(xlabel="time after contact (us)", ylabel="u_z of the plate's leading 0.3 mm on the axis (km/s)")
    a.set_ylim(3.0, 7.2)
    a.legend(fontsize=8, loc="lower right")
    U, z, h = reference
    rho = (U[4] + U[5]) / 2785.0
    r_edge = np.arange(U.shape[1] + 1) * h * 1e3
    z_edge = np.concatenate([z - h / 2, [z[-1] + h / 2]]) * 1e3
    b.pcolormesh(-r_edge, z_edge, rho.T, cmap="Greys", vmin=0, vmax=1.2, shading="flat")
    x, is_plate, res = particles
    b.scatter(x[~is_plate, 0] * 1e3, x[~is_plate, 1] * 1e3, s=0.3, c="tab:red", label="projectile")
    b.scatter(x[is_plate, 0] * 1e3, x[is_plate, 1] * 1e3, s=0.3, c="tab:blue", label="plate")
    b.set(
        xlabel="r (mm): reference's density / rho0 (left), jaxmpm's particles (right)",
        ylabel="z (mm)",
        title=f"6 us: reference {h * 1e3:g} mm cells | jaxmpm hydrodynamic, resolution {res:g}",
        aspect="equal",
        xlim=(-22, 22),
        ylim=(-42, 8),
    )
    b.legend(fontsize=8, markerscale=20, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--reference-cells", type=float, nargs="+", default=[0.2, 0.1], help="mm")
    ap.add_argument("--resolutions", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    ap.add_argument("--c-h", type=float, default=0.02, help="C_h of the 'jaxmpm scene' rows")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "debris_cloud_reference.csv"))
    add_overwrite(ap)
    a = ap.parse_args()
    png = os.path.splitext(a.out)[0] + ".png"
    check_outputs(a.out, png, overwrite=a.overwrite)
    jax.config.update("jax_enable_x64", True)

    from axisymmetric_euler import debris_cloud, hydrodynamic_debris_cloud, mpm_axial_slices

    import jaxmpm
    from jaxmpm.materials import library_material

    al = dict(library_material("al2024", model="mie_gruneisen").constants)
    rows, curves = [], []
    for cells in a.reference_cells:
        ref = debris_cloud(al, cells * 1e-3)
        rows.append(row("reference", cells, ref))
        curves.append((f"reference, {cells:g} mm", ref["t"], ref["plate"]))
        print(rows[-1], flush=True)
    for res in a.resolutions:
        for code, scene in (
            ("jaxmpm hydrodynamic", hydrodynamic_debris_cloud(res)),
            ("jaxmpm scene", jaxmpm.load_scene("debris_cloud", resolution=res, fragmentation="tensile", c_h=a.c_h)),
        ):
            run = mpm_axial_slices(scene)
            rows.append(row(code, 0.4 / res, run))
            curves.append((f"{code}, {0.4 / res:.3g} mm", run["t"], run["plate"]))
            if code == "jaxmpm hydrodynamic":
                particles = (run["x"], run["is_plate"], res)
            print(rows[-1], flush=True)
    print(
        f"the debris cloud's axis, 3-6 us, km/s (experiment's leading edge {EXPERIMENT}), float64, {describe()}, "
        f"{os.cpu_count()} CPUs, jax {jax.__version__}, {platform.machine()}"
    )
    print_and_write_table(rows, a.out, width=22)
    figure(png, curves, (ref["U"], ref["z"], a.reference_cells[-1] * 1e-3), particles)
    print(f"wrote {a.out} and {png}")


if __name__ == "__main__":
    main()
