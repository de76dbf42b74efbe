"""Regenerate the Chebyshev tables of paintjax.wave._hankel (needs mpmath: `pip install mpmath`).

For x ≥ X0 the Hankel functions are written H_n(x) = √(2/(πx)) (P_n + iQ_n) exp{i(x − (2n+1)π/4)}
with P_n = f_n(s), Q_n = (X0/x) g_n(s), s = (X0/x)² ∈ (0, 1]; f_n and g_n are fitted by Chebyshev
series in u = 2s − 1 to mpmath values at 40 digits. Run: `python experiments/hankel_coefficients.py`
and paste the printed tables into paintjax/_hankel.py.
"""

import mpmath as mp
import numpy as np

X0 = 7.0
DEGREE = 17
mp.mp.dps = 40


def pq(n: int, x: mp.mpf):
    h = (mp.besselj(n, x) + 1j * mp.bessely(n, x)) * mp.sqrt(mp.pi * x / 2) * mp.exp(-1j * (x - (2 * n + 1) * mp.pi / 4))
    return mp.re(h), mp.im(h)


def fit(n: int):
    """Chebyshev interpolation at m nodes, coefficients by an exact (mpmath) discrete cosine transform."""
    m = 64
    nodes = [mp.cos(mp.pi * (i + mp.mpf(1) / 2) / m) for i in range(m)]
    fs, gs = [], []
    for u in nodes:
        x = mp.mpf(X0) / mp.sqrt((u + 1) / 2)
        p, q = pq(n, x)
        fs.append(p)
        gs.append(q * x / X0)
    cf, cg = [], []
    for j in range(DEGREE + 1):
        w = [mp.cos(j * mp.pi * (i + mp.mpf(1) / 2) / m) * 2 / m for i in range(m)]
        cf.append(mp.fsum(a * b for a, b in zip(fs, w)))
        cg.append(mp.fsum(a * b for a, b in zip(gs, w)))
    cf[0] /= 2
    cg[0] /= 2
    cf = np.array([float(c) for c in cf])
    cg = np.array([float(c) for c in cg])
    err = 0.0
    for si in np.linspace(1e-6, 1, 301):
        x = mp.mpf(X0) / mp.sqrt(mp.mpf(si))
        p, q = pq(n, x)
        uu = 2 * si - 1
        err = max(err, abs(np.polynomial.chebyshev.chebval(uu, cf) - float(p)), abs(np.polynomial.chebyshev.chebval(uu, cg) - float(q * x / X0)))
    return cf, cg, err


if __name__ == "__main__":
    for n in (0, 1):
        cf, cg, err = fit(n)
        print(f"# order {n}: max abs fit error {err:.2e}")
        print(f"_P{n} = (" + ", ".join(repr(float(c)) for c in cf) + ")")
        print(f"_Q{n} = (" + ", ".join(repr(float(c)) for c in cg) + ")")
