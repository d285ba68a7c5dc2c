"""Displacement-force creep model of a test specimen (SI eq. 9).

    x(h, b, t, F) = p_dry(h, b, F) + integral_0^t F exp(p_wet(h, b, tau, F)) dtau

``p_dry`` [mm] is the dry displacement polynomial, ``p_wet`` [ln(mm min^-1 N^-1)] the log creep
rate per unit load; h, b in mm, F the specimen load in N (4 brackets), t in **minutes** inside this
module (the fit's unit; public model APIs take seconds).

Two ways to evaluate the integral are implemented:

* ``"gauss"``: composite Gauss-Legendre on 0.1 min panels (6 points per panel by default); the
  integrand ``exp(poly4(t))`` is smooth, and halving the panels changes x by < 1e-9 mm on the fit
  grid (checked in the tests);
* ``"euler6"``: the authors' left Riemann sum with a 0.1 min (6 s) step, evaluated at the panel
  nodes and linearly interpolated in between (what a model tabulated on a 6 s grid would give).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .polyfit import design_matrix, mv

INTEGRATIONS = ("gauss", "euler6")


@dataclass
class CreepModel:
    """The fitted ``p_dry`` and ``p_wet`` polynomials.

    Attributes
    ----------
    E_dry : (m, 3) int
        Exponents of (h, b, F).
    beta_dry : (m,) float
    E_wet : (k, 4) int
        Exponents of (h, b, F, t).
    beta_wet : (k,) float
    """

    E_dry: np.ndarray
    beta_dry: np.ndarray
    E_wet: np.ndarray
    beta_wet: np.ndarray

    def dry(self, h, b, F) -> np.ndarray:
        """``p_dry`` : (n,) float, mm, for (n,) h, b (mm) and F (N)."""
        X = np.c_[np.ravel(h), np.ravel(b), np.ravel(F)]
        return mv(design_matrix(self.E_dry, X), self.beta_dry)

    def ln_rate(self, h, b, F, t_min) -> np.ndarray:
        """``p_wet`` : (n,) float, ln(mm min^-1 N^-1)."""
        X = np.c_[np.ravel(h), np.ravel(b), np.ravel(F), np.ravel(t_min)]
        return mv(design_matrix(self.E_wet, X), self.beta_wet)

    def time_coefficients(self, h, b, F) -> np.ndarray:
        """Coefficients of ``p_wet`` as a polynomial in t: (n, d+1), lowest power first."""
        X = np.c_[np.ravel(h), np.ravel(b), np.ravel(F)]
        deg = int(self.E_wet[:, 3].max())
        out = np.zeros((X.shape[0], deg + 1))
        for k in range(deg + 1):
            sel = self.E_wet[:, 3] == k
            if np.any(sel):
                out[:, k] = mv(design_matrix(self.E_wet[sel, :3], X),
                                  self.beta_wet[sel])
        return out

    def creep_at_nodes(self, h, b, F, n_panels: int, panel: float = 0.1,
                       integration: str = "gauss", gauss_points: int = 6) -> np.ndarray:
        """Creep displacement ``integral_0^t F exp(p_wet)`` at ``t_k = k * panel``.

        Parameters
        ----------
        h, b, F : (n,) float
        n_panels : int
        panel : float, min
        integration : {"gauss", "euler6"}
        gauss_points : int

        Returns
        -------
        (n, n_panels + 1) float, mm
        """
        F = np.ravel(F).astype(float)
        a = self.time_coefficients(h, b, F)
        if integration == "euler6":
            tk = panel * np.arange(n_panels)
            inc = np.exp(_horner(a, tk[None, :])) * panel
        elif integration == "gauss":
            g, wg = np.polynomial.legendre.leggauss(gauss_points)
            tq = panel * (np.arange(n_panels)[:, None] + 0.5 * (g[None, :] + 1.0))  # (K, q)
            vals = np.exp(_horner(a, tq.reshape(1, -1))).reshape(len(F), n_panels, -1)
            inc = np.einsum("ijk,k->ij", vals, 0.5 * panel * wg)
        else:
            raise ValueError(f"integration must be one of {INTEGRATIONS}, got {integration!r}")
        return F[:, None] * np.concatenate([np.zeros((len(F), 1)), np.cumsum(inc, axis=1)],
                                           axis=1)

    def displacement(self, h, b, F, t_min, integration: str = "gauss", panel: float = 0.1,
                     gauss_points: int = 6) -> np.ndarray:
        """SI eq. 9 at arbitrary times.

        Parameters
        ----------
        h, b : (n,) float, mm
        F : (n,) float, N
            Specimen load.
        t_min : (n,) float, min
            Time in water (>= 0).
        integration : {"gauss", "euler6"}

        Returns
        -------
        x : (n,) float, mm
        """
        h, b, F, t = (np.ravel(v).astype(float) for v in np.broadcast_arrays(h, b, F, t_min))
        t = np.maximum(t, 0.0)
        x0 = self.dry(h, b, F)
        if len(t) == 0:
            return x0
        K = int(np.ceil(t.max() / panel)) + 1
        nodes = self.creep_at_nodes(h, b, F, K, panel, integration, gauss_points)
        k = np.minimum((t / panel).astype(int), K - 1)
        rows = np.arange(len(t))
        if integration == "euler6":
            frac = t / panel - k
            creep = (1.0 - frac) * nodes[rows, k] + frac * nodes[rows, k + 1]
        else:
            # full panels from the node table, then the partial panel [k*panel, t]
            g, wg = np.polynomial.legendre.leggauss(gauss_points)
            lo = k * panel
            half = 0.5 * (t - lo)
            tq = lo[:, None] + half[:, None] * (g[None, :] + 1.0)
            a = self.time_coefficients(h, b, F)
            part = mv(np.exp(_horner(a, tq)), wg) * half * F
            creep = nodes[rows, k] + part
        return x0 + creep

    def to_dict(self) -> dict:
        return {"dry": {"variables": ["h_mm", "b_mm", "F_N"], "unit": "mm",
                        "exponents": self.E_dry.tolist(), "coefficients": self.beta_dry.tolist()},
                "wet": {"variables": ["h_mm", "b_mm", "F_N", "t_min"],
                        "unit": "ln(mm min^-1 N^-1)",
                        "exponents": self.E_wet.tolist(), "coefficients": self.beta_wet.tolist()}}

    @classmethod
    def from_dict(cls, d: dict) -> CreepModel:
        return cls(np.asarray(d["dry"]["exponents"], dtype=np.int64),
                   np.asarray(d["dry"]["coefficients"], dtype=float),
                   np.asarray(d["wet"]["exponents"], dtype=np.int64),
                   np.asarray(d["wet"]["coefficients"], dtype=float))


def _horner(a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Evaluate rows of ``a`` (n, d+1), lowest power first, at ``t`` broadcast to (n, q)."""
    out = np.zeros(np.broadcast_shapes((a.shape[0], 1), t.shape))
    for k in range(a.shape[1] - 1, -1, -1):
        out = out * t + a[:, k:k + 1]
    return out
