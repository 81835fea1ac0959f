"""Prominent individuals ("queens", paper 2 Sec. 3.1, Algorithm 1).

Every pixel of every template is one RGB feature ``phi``; a map ``Omega`` keeps the template
each feature came from. The features are clustered by a Gaussian mixture (EM, full
covariances, :func:`fit_gmm`), the clusters are sorted by a criterion (the paper's choice:
*density* ``m / v`` in ascending order, so sparse clusters -- outlying colours -- come first,
with mass ``m = |C|`` and volume ``v = (2 pi)^{3/2} |Sigma|^{1/2}``), and the features are
given back to their templates cluster by cluster. The process stops as soon as
``queen_fraction`` (10 %) of the templates are filled to ``fill_fraction`` (2/3) of their
pixels; the filled templates are the queens. All features of one cluster are given back at
once, so more than 10 % may be selected (as in the paper).

OpenCV's ``cv2.ml.EM`` is not part of the headless OpenCV wheel this project uses, and
scikit-learn is not a dependency, so the mixture is fitted here in numpy: k-means
initialisation (k-means++ seeds from an injected generator, a few Lloyd steps), then EM with
a covariance floor ``reg * I`` (RGB units^2). The mixture is fitted on at most
``max_samples`` features drawn at random; every feature is then hard-assigned to its most
responsible component, which gives the masses ``m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

QUEEN_ORDERS: tuple[str, ...] = ("density", "mass", "volume", "mass_volume", "inverse_density")
"""Cluster sort criteria the paper compared (ascending): ``m/v``, ``m``, ``v``, ``m v``,
``v/m``; density was the most stable and is the default."""


@dataclass
class GaussianMixture:
    """A fitted mixture of ``k`` 3-D Gaussians.

    Attributes
    ----------
    weights : (k,) float64
        Mixing weights (sum 1).
    means : (k, 3) float64
        Component means ``mu``, RGB units.
    covariances : (k, 3, 3) float64
        Component covariances ``Sigma`` (floor ``reg * I`` included), RGB units^2.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray

    @property
    def k(self) -> int:
        return len(self.weights)

    def _log_gauss(self, x: np.ndarray, outer: np.ndarray | None = None) -> np.ndarray:
        """``(N, k)`` log ``N(x | mu_k, Sigma_k)``; ``outer`` is ``(N, 9)`` ``x x^T`` if known.

        The Mahalanobis term is expanded, ``x^T P x - 2 mu^T P x + mu^T P mu`` with
        ``P = Sigma^-1``, so that it is two matrix products over all points and components.
        """
        prec = np.linalg.inv(self.covariances)  # (k, 3, 3)
        if outer is None:
            outer = (x[:, :, None] * x[:, None, :]).reshape(len(x), 9)
        pm = np.einsum("kde,ke->kd", prec, self.means)  # (k, 3)
        maha = outer @ prec.reshape(-1, 9).T - 2.0 * (x @ pm.T) + (pm * self.means).sum(1)
        _, logdet = np.linalg.slogdet(self.covariances)
        return -0.5 * (np.maximum(maha, 0.0) + logdet[None] + 3.0 * math.log(2.0 * math.pi))

    def log_responsibilities(
        self, x: np.ndarray, outer: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(N, k)`` log posterior of each component and ``(N,)`` log-likelihood of ``x``."""
        lp = self._log_gauss(x, outer) + np.log(np.maximum(self.weights, 1e-300))[None]
        top = lp.max(1, keepdims=True)
        ll = top[:, 0] + np.log(np.exp(lp - top).sum(1))
        return lp - ll[:, None], ll

    def predict(self, x: np.ndarray, batch: int = 65536) -> np.ndarray:
        """``(N,)`` int64 most responsible component of each row of ``x`` ``(N, 3)``."""
        x = np.asarray(x, np.float64).reshape(-1, 3)
        out = np.empty(len(x), np.int64)
        for a in range(0, len(x), batch):
            lr, _ = self.log_responsibilities(x[a : a + batch])
            out[a : a + batch] = lr.argmax(1)
        return out

    @property
    def volumes(self) -> np.ndarray:
        """``(k,)`` volume ``v = (2 pi)^{3/2} |Sigma|^{1/2}`` of each component (Sec. 3.1)."""
        return (2.0 * math.pi) ** 1.5 * np.sqrt(np.linalg.det(self.covariances))


def _kmeanspp(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """``(k, 3)`` k-means++ seeds (outlying colours are picked early, D^2 sampling)."""
    centers = np.empty((k, x.shape[1]))
    centers[0] = x[rng.integers(len(x))]
    d2 = ((x - centers[0]) ** 2).sum(1)
    for c in range(1, k):
        total = d2.sum()
        if total <= 0:  # fewer distinct points than k: repeat the first centre
            centers[c:] = centers[0]
            break
        centers[c] = x[rng.choice(len(x), p=d2 / total)]
        d2 = np.minimum(d2, ((x - centers[c]) ** 2).sum(1))
    return centers


def _m_step(r: np.ndarray, x: np.ndarray, outer: np.ndarray, eye: np.ndarray) -> GaussianMixture:
    """Maximisation step from responsibilities ``r`` ``(N, k)``; ``outer`` is ``x x^T``."""
    k = r.shape[1]
    nk = r.sum(0) + 1e-12
    means = (r.T @ x) / nk[:, None]
    second = (r.T @ outer).reshape(k, 3, 3) / nk[:, None, None]
    cov = second - means[:, :, None] * means[:, None, :]
    cov = 0.5 * (cov + cov.transpose(0, 2, 1)) + eye
    return GaussianMixture(nk / nk.sum(), means, cov)


def fit_gmm(
    x: np.ndarray,
    k: int,
    rng: np.random.Generator,
    *,
    iterations: int = 30,
    reg: float = 1.0,
    tol: float = 1e-4,
    kmeans_iterations: int = 5,
) -> GaussianMixture:
    """Fit a full-covariance Gaussian mixture to ``x`` ``(N, 3)`` by EM.

    Parameters
    ----------
    x : (N, 3) float
        Features (RGB of template pixels).
    k : int
        Components; reduced to the number of distinct rows of ``x`` when that is smaller.
    rng : numpy.random.Generator
        Seeds the k-means++ initialisation.
    iterations : int
        Maximum EM iterations.
    reg : float
        Covariance floor added to every ``Sigma`` diagonal, units^2 (a cluster of identical
        colours would otherwise have zero volume).
    tol : float
        Stop when the mean log-likelihood improves by less than this.
    kmeans_iterations : int
        Lloyd iterations of the k-means initialisation.
    """
    x = np.asarray(x, np.float64).reshape(-1, 3)
    if len(x) == 0:
        raise ValueError("fit_gmm needs at least one feature")
    k = int(max(1, min(k, len(np.unique(x, axis=0)))))
    outer = (x[:, :, None] * x[:, None, :]).reshape(len(x), 9)
    eye = np.eye(3) * reg
    # initialise as scikit-learn does: k-means (k-means++ seeds, a few Lloyd steps), then
    # weights, means and covariances of the hard clusters
    means = _kmeanspp(x, k, rng)
    for _ in range(kmeans_iterations):
        label = (-2.0 * (x @ means.T) + (means * means).sum(1)[None]).argmin(1)
        nk = np.bincount(label, minlength=k).astype(np.float64)
        sums = np.zeros((k, 3))
        np.add.at(sums, label, x)
        means = np.where(nk[:, None] > 0, sums / np.maximum(nk, 1.0)[:, None], means)
    resp = np.zeros((len(x), k))
    resp[np.arange(len(x)), label] = 1.0
    gm = _m_step(resp, x, outer, eye)
    prev = -np.inf
    for _ in range(iterations):
        lr, ll = gm.log_responsibilities(x, outer)
        gm = _m_step(np.exp(lr), x, outer, eye)
        mean_ll = float(ll.mean())
        if mean_ll - prev < tol:
            break
        prev = mean_ll
    return gm


def cluster_order_key(mass: np.ndarray, volume: np.ndarray, order: str) -> np.ndarray:
    """``(k,)`` sort key of the clusters (ascending) for the criterion ``order``."""
    if order == "density":
        return mass / volume
    if order == "mass":
        return mass.astype(np.float64)
    if order == "volume":
        return volume
    if order == "mass_volume":
        return mass * volume
    if order == "inverse_density":
        return volume / np.maximum(mass, 1e-300)
    raise ValueError(f"unknown cluster order {order!r}; expected one of {QUEEN_ORDERS}")


def back_assign(
    labels: np.ndarray,
    owner: np.ndarray,
    rank: np.ndarray,
    n_templates: int,
    pixels: int,
    queen_fraction: float,
    fill_fraction: float,
) -> np.ndarray:
    """Algorithm 1's back-assignment: ``(n_templates,)`` bool, the queens.

    Parameters
    ----------
    labels : (N,) int
        Cluster of every feature.
    owner : (N,) int
        Template of every feature (the map ``Omega``).
    rank : (k,) int
        Position of each cluster in the sorted list (0 is given back first).
    n_templates, pixels : int
        Number of templates and pixels per template.
    queen_fraction, fill_fraction : float
        Stop once ``ceil(queen_fraction n)`` templates (at least one) hold at least
        ``fill_fraction`` of their pixels.

    Template 0 holds features of clusters 0, 0, 1 and template 1 of 1, 1, 1; cluster 1 is
    given back first and fills template 1 alone:

    >>> back_assign(np.array([0, 0, 1, 1, 1, 1]), np.array([0, 0, 0, 1, 1, 1]),
    ...             np.array([1, 0]), 2, 3, 0.1, 2 / 3).tolist()
    [False, True]
    """
    if n_templates == 0:
        return np.zeros(0, bool)
    k = len(rank)
    counts = np.bincount(owner * k + rank[labels], minlength=n_templates * k)
    cum = np.cumsum(counts.reshape(n_templates, k), axis=1)
    filled = cum >= fill_fraction * pixels - 1e-9  # (n, k): filled after the first c clusters
    need = max(1, math.ceil(queen_fraction * n_templates - 1e-9))
    done = np.flatnonzero(filled.sum(0) >= need)
    c = int(done[0]) if len(done) else k - 1
    return filled[:, c].copy()


def select_queens(
    templates: np.ndarray,
    rng: np.random.Generator,
    *,
    n_clusters: int = 100,
    min_cluster_pixels: int = 20,
    queen_fraction: float = 0.1,
    fill_fraction: float = 2.0 / 3.0,
    order: str = "density",
    iterations: int = 30,
    max_samples: int = 10000,
    reg: float = 1.0,
) -> np.ndarray:
    """Queens among ``templates`` ``(n, s, s, 3)`` uint8 (Algorithm 1); ``(n,)`` bool.

    ``k = min(n_clusters, N // min_cluster_pixels)`` components for ``N = n s^2`` features
    (fewer pixels, fewer clusters; at least one).
    """
    templates = np.asarray(templates)
    n = templates.shape[0]
    if n == 0:
        return np.zeros(0, bool)
    pixels = templates.shape[1] * templates.shape[2]
    x = templates.reshape(n * pixels, 3).astype(np.float64)
    owner = np.repeat(np.arange(n), pixels)
    k = max(1, min(n_clusters, len(x) // max(1, min_cluster_pixels)))
    fit = x if len(x) <= max_samples else x[np.sort(rng.choice(len(x), max_samples, replace=False))]
    gm = fit_gmm(fit, k, rng, iterations=iterations, reg=reg)
    labels = gm.predict(x)
    mass = np.bincount(labels, minlength=gm.k)
    key = cluster_order_key(mass, gm.volumes, order)
    rank = np.empty(gm.k, np.int64)
    rank[np.argsort(key, kind="stable")] = np.arange(gm.k)
    return back_assign(labels, owner, rank, n, pixels, queen_fraction, fill_fraction)
