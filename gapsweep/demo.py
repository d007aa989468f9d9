"""Built-in default job, field-theory part: the paper's figure 2 (docs/model.md M4, M6).

Mean gap ``g0/h_rms`` against ``sigma0/(E* g_rms)`` for H = 0.3 and rho/L = 2e-3, 1e-3, 5e-4, with the high- and
low-pressure limits, printed as a table and drawn as a PNG. Continuum ``h_rms`` of the g_rms = 1 spectrum.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gapsweep import surface, theory

FIG2 = {"hurst": 0.3, "lambda_l": 0.25, "lambda_s": 2.5e-3, "gamma0": 1e-3, "e_star": 1.0, "rms_slope": 1.0}
FIG2_RHOS = (2e-3, 1e-3, 5e-4)


def fig2_theory_table(pressures: np.ndarray | None = None) -> tuple[np.ndarray, dict[float, dict[str, np.ndarray]]]:
    """Field-theory mean gap (paper form, M4) and both limits, in units of h_rms, per rho."""
    p = FIG2
    sig = np.logspace(-4, 0, 9) if pressures is None else np.asarray(pressures, dtype=float)
    h_rms = surface.continuum_rms_height(p["hurst"], lambda_l=p["lambda_l"], lambda_s=p["lambda_s"])
    common = dict(hurst=p["hurst"], h_rms=h_rms, gamma0=p["gamma0"], lambda_l=p["lambda_l"],
                  lambda_s=p["lambda_s"], e_star=p["e_star"])
    out = {}
    for rho in FIG2_RHOS:
        out[rho] = {
            "theory": theory.mean_gap(sig, rho=rho, **common) / h_rms,
            "high": theory.flat_gap(sig, rho=rho, gamma0=p["gamma0"]) / h_rms,
            "low": (theory.flat_gap(sig, rho=rho, gamma0=p["gamma0"]) + h_rms**2 / (2 * rho)) / h_rms,
        }
    return sig, out


def fig2_theory(out_dir: str | Path = "out") -> str:
    """Print the figure-2 field-theory table and write ``fig2_theory.png`` into ``out_dir``; returns the table."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sig, curves = fig2_theory_table()
    head = "sigma0/(E* g_rms) | " + " | ".join(f"g0/h_rms rho={r:g}" for r in FIG2_RHOS)
    lines = [head, "-" * len(head)]
    for i, s in enumerate(sig):
        lines.append(f"{s:17.3e} | " + " | ".join(f"{curves[r]['theory'][i]:17.4f}" for r in FIG2_RHOS))
    table = "\n".join(lines)

    dense, dcurves = fig2_theory_table(np.logspace(-4.5, 0.5, 200))
    fig, ax = plt.subplots(figsize=(5.5, 4.2), constrained_layout=True)
    for rho, color in zip(FIG2_RHOS, ("C0", "C1", "C2")):
        c = dcurves[rho]
        ax.semilogx(dense, c["theory"], color=color, label=f"field theory, rho/L = {rho:g}")
        ax.semilogx(dense, c["high"], color=color, ls="--", lw=0.8)
        ax.semilogx(dense, c["low"], color=color, ls=":", lw=0.8)
    ax.set_xlabel(r"$\sigma_0/(E^* \bar g)$")
    ax.set_ylabel(r"$g_0/h_\mathrm{rms}$")
    ax.set_title("Fig. 2 (field theory): H = 0.3; dashed: high-, dotted: low-pressure limit", fontsize=8)
    ax.legend(fontsize=8)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "fig2_theory.png", dpi=150)
    plt.close(fig)
    return table
