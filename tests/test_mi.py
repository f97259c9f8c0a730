"""The MI estimator against a direct, loop-by-loop reference computation of the paper's recipe."""

import numpy as np
import pytest

from l2e_studio.scoring.mi import N_BINS, kernel_matrix, mutual_information, silverman_bandwidth

RNG = np.random.default_rng(3)


def reference_mi(L, E):
    """Algorithm 1 of the paper, then normalise by n, KDE-smooth (Silverman) and take entropies.

    Written the slow, obvious way: Python loops over points and bins.
    """
    n = len(L)
    hist_l = np.zeros(N_BINS)
    hist_e = np.zeros(N_BINS)
    hist_le = np.zeros((N_BINS, N_BINS))
    for l, e in zip(L, E):
        hist_l[l] += 1
        hist_e[e] += 1
        hist_le[l, e] += 1
    h_l = 1.06 * np.std(L) * n ** (-0.2)
    h_e = 1.06 * np.std(E) * n ** (-0.2)

    def spread(h):
        # each bin's mass spreads over its neighbours with normalised Gaussian weights (4 widths),
        # mass falling past an end is mirrored back inside
        S = np.zeros((N_BINS, N_BINS))
        r = int(4 * h + 0.5)
        w = np.array([np.exp(-0.5 * (k / h) ** 2) for k in range(-r, r + 1)])
        w /= w.sum()
        for src in range(N_BINS):
            for k, wk in zip(range(-r, r + 1), w):
                dst = src + k
                if dst < 0:
                    dst = -dst - 1
                if dst >= N_BINS:
                    dst = 2 * N_BINS - dst - 1
                S[dst, src] += wk
        return S

    S_l, S_e = spread(h_l), spread(h_e)
    p_l = S_l @ hist_l / n
    p_e = S_e @ hist_e / n
    p_le = S_l @ hist_le @ S_e.T / n

    def H(p):
        return -sum(x * np.log(x) for x in p.ravel() if x > 0)

    return H(p_l) + H(p_e) - H(p_le)


@pytest.mark.parametrize("dependence", [0.0, 0.5, 1.0])
def test_mi_matches_direct_reference(dependence):
    n = 3000
    L = RNG.integers(0, 256, n)
    noise = RNG.integers(0, 128, n)
    E = np.clip((dependence * L / 2 + (1 - dependence) * noise + RNG.normal(0, 3, n)).astype(int), 0, 127)
    assert mutual_information(L, E) == pytest.approx(reference_mi(L, E), rel=1e-9, abs=1e-12)


def test_mi_grows_with_dependence_and_is_near_zero_for_independent_samples():
    n = 20000
    L = RNG.integers(0, 256, n)
    independent = mutual_information(L, RNG.integers(0, 128, n))
    dependent = mutual_information(L, np.clip(L // 2 + RNG.integers(-4, 5, n), 0, 127))
    assert independent < 0.02
    assert dependent > 1.0


def test_kernel_matrix_preserves_mass_and_equals_gaussian_filter_inside():
    from scipy.ndimage import gaussian_filter1d

    A = kernel_matrix(3.7)
    assert np.allclose(A.sum(axis=0), 1.0)
    x = np.zeros(N_BINS)
    x[100] = 1.0
    assert np.allclose(A @ x, gaussian_filter1d(x, 3.7, mode="reflect", truncate=4.0), atol=1e-12)


def test_silverman_rule():
    x = RNG.normal(0, 10.0, 100000)
    assert silverman_bandwidth(x) == pytest.approx(1.06 * x.std() * 100000 ** (-0.2))
    assert silverman_bandwidth(np.ones(10)) == 0.0
