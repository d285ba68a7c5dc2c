"""Is the tolerance run's per-print compliance draw right? (issue #45, item 1; not a test).

The tolerance analysis draws one bracket compliance per print, ``s = exp(sd z)``, ``z`` the
4th standard normal after the print's thickness draws of ``default_rng([seed, i])``
(:func:`pysolver.tolerance.analysis._draw`), ``sd`` the robust sd of ``ln r`` over the wet
test curves (:func:`pysolver.tolerance.analysis.material_scatter`).  This prints:

1. the sampler: ``z`` of samples ``0..N-1`` of seed 0 for a shell of ``--cells`` cells (mean,
   sd, Kolmogorov-Smirnov p against N(0, 1), the smallest ``z`` and how often ``|z| > 3.9``),
   and the first samples' ``z``;
2. the distribution it draws from: the 80 curves' ``ln r`` (median, sd, robust sd,
   Shapiro-Wilk p, the extreme robust ``z``), and whether the load or the bracket geometry
   explains part of it (one-way ANOVA p; the robust sd with the per-load medians removed);
3. the odds of a draw at least as low as ``--z``: one draw, and at least one in 20 and 32.

Usage::

    .venv/bin/python bench/compliance_draw.py [--samples 20000] [--cells 238] [--z -3.9]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def sampler(n: int, cells: int) -> dict:
    from pysolver.params import UNCERTAINTY
    from pysolver.tolerance.analysis import _draw

    unc = dataclasses.replace(UNCERTAINTY, material_sd=1.0)
    z = np.array([math.log(_draw(0, i, cells, unc, 1.0)["material"]) for i in range(n)])
    return {"n": n, "mean": float(z.mean()), "sd": float(z.std(ddof=1)),
            "ks_p": float(stats.kstest(z, "norm").pvalue), "min": float(z.min()),
            "share_abs_over_3_9": float(np.mean(np.abs(z) > 3.9)),
            "first_20": [round(float(v), 2) for v in z[:20]]}


def curves() -> dict:
    """``ln r`` of every wet curve (as :func:`material_scatter` computes it), with its load
    and geometry."""
    from pysolver.material.measurements import SPECIMEN_BRACKETS, load_measurements, wet_eval_rows
    from pysolver.material.model import load_bracket_model

    mod = load_bracket_model(None)
    obs = wet_eval_rows(load_measurements(None).wet, float(mod.grid_max[2]))
    x = mod.compression_for_force(obs.h, obs.b, obs.t * 60.0, obs.F / SPECIMEN_BRACKETS)
    rows = []
    for k in np.unique(obs.series):
        m = (obs.series == k) & np.isfinite(x)
        den = float(np.sum(x[m] ** 2))
        r = float(np.sum(x[m] * obs.x[m]) / den) if m.sum() >= 3 and den > 0 else 0.0
        if r > 0:
            rows.append((obs.h[m][0], obs.b[m][0], min(obs.F[m][0], 4.0), math.log(r)))
    return np.array(rows)


def distribution(a) -> dict:
    L = a[:, 3]
    med = float(np.median(L))
    rsd = 1.4826 * float(np.median(np.abs(L - med)))
    by_load = [L[a[:, 2] == f] for f in np.unique(a[:, 2])]
    geo = {(round(h, 3), round(b, 2)) for h, b in a[:, :2]}
    by_geo = [L[(np.round(a[:, 0], 3) == h) & (np.round(a[:, 1], 2) == b)] for h, b in geo]
    res = L.copy()
    for f in np.unique(a[:, 2]):
        res[a[:, 2] == f] -= np.median(L[a[:, 2] == f])
    return {"curves": int(len(L)), "median": med, "sd": float(L.std(ddof=1)), "robust_sd": rsd,
            "shapiro_p": float(stats.shapiro(L).pvalue),
            "robust_z_range": [float((L.min() - med) / rsd), float((L.max() - med) / rsd)],
            "lowest_ratio_to_median": float(math.exp(L.min() - med)),
            "load_anova_p": float(stats.f_oneway(*by_load).pvalue),
            "geometry_anova_p": float(stats.f_oneway(*by_geo).pvalue),
            "robust_sd_without_load_medians":
                1.4826 * float(np.median(np.abs(res - np.median(res))))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--cells", type=int, default=238)
    ap.add_argument("--z", type=float, default=-3.9)
    a = ap.parse_args()
    p = float(stats.norm.cdf(a.z))
    out = {"sampler": sampler(a.samples, a.cells), "distribution": distribution(curves()),
           "odds": {"one_draw": p, "any_of_20": 1 - (1 - p) ** 20, "any_of_32": 1 - (1 - p) ** 32}}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
